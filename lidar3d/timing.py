"""Wall-clock timing of named stages, for the per-stage figures in ``summary.json``."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["StageClock"]


class StageClock:
    """Milliseconds spent per named stage: ``with clock("odometry"): ...``.

    Attributes:
        ms: stage name -> wall milliseconds summed over the ``with`` blocks of that name.
    """

    def __init__(self) -> None:
        self.ms: dict[str, float] = {}

    @contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.ms[stage] = self.ms.get(stage, 0.0) + (time.perf_counter() - t0) * 1e3
