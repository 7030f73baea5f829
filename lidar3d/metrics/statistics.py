"""Summary statistics of an error series."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["ErrorStatistics"]


@dataclass(frozen=True, slots=True)
class ErrorStatistics:
    """RMSE, mean, median, standard deviation, min and max of non-negative errors (NaN when n = 0)."""

    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float
    n: int

    @classmethod
    def of(cls, errors: np.ndarray) -> ErrorStatistics:
        """Statistics of a 1-D error array (rmse = sqrt(mean(e^2)), as evo and TUM compute it)."""
        e = np.asarray(errors, dtype=np.float64).reshape(-1)
        if e.size == 0:
            nan = math.nan
            return cls(nan, nan, nan, nan, nan, nan, 0)
        return cls(
            rmse=float(np.sqrt(np.mean(e * e))),
            mean=float(np.mean(e)),
            median=float(np.median(e)),
            std=float(np.std(e)),
            min=float(np.min(e)),
            max=float(np.max(e)),
            n=int(e.size),
        )
