"""Compiled kernels (numba) that cost nothing until first used.

``@lazy_njit`` marks a plain Python function as a numba kernel (``nopython``, ``cache=True``,
``nogil=True``). numba is imported and the kernel compiled, or loaded from numba's on-disk cache,
at the kernel's first call, so a process that never calls it (the main process of a run whose front
end runs in the prefetch process, the dense map's process) does not pay numba's import (0.2-0.4 s
CPU) or its memory (about 110 MB: LLVM). The first call ever compiles (about 1-2 s per kernel);
later processes load the cache (about 0.3 s for the first kernel, then milliseconds).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

__all__ = ["lazy_njit"]


class _LazyKernel:
    """A function compiled by numba at its first call."""

    __slots__ = ("_compiled", "_function")

    def __init__(self, function: Callable[..., Any]) -> None:
        self._function = function
        self._compiled: Callable[..., Any] | None = None

    def __call__(self, *args: Any) -> Any:
        if self._compiled is None:
            from numba import njit

            self._compiled = njit(cache=True, nogil=True)(self._function)
        return self._compiled(*args)

    @property
    def py_func(self) -> Callable[..., Any]:
        """The plain Python function (the same results, slowly)."""
        return self._function


def lazy_njit(function: Callable[..., Any]) -> _LazyKernel:
    """Decorator: ``function`` compiled by numba at its first call (see the module doc)."""
    return _LazyKernel(function)
