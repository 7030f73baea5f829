"""Projection of nearly rigid 4x4 matrices back onto SE(3).

Poses that go round the loop-closure cycle (pose-graph estimate -> correction -> initial guess ->
ICP -> loop factor -> estimate) pick up rounding off SO(3); GTSAM keeps a ``Rot3`` built from a
matrix as given and its compose/retract amplify the defect (about fourfold per closure in our
runs, until iSAM2 reports an indeterminant system). Every pose entering the pose graph or leaving
this package is therefore projected with :func:`nearest_rigid`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["nearest_rigid"]


def nearest_rigid(T: np.ndarray) -> np.ndarray:
    """The rigid transform(s) nearest to ``T`` (4,4) or (...,4,4): rotation by SVD (Frobenius-nearest
    rotation, det +1), translation kept, last row (0, 0, 0, 1)."""
    T = np.asarray(T, dtype=np.float64)
    U, _, Vt = np.linalg.svd(T[..., :3, :3])
    d = np.sign(np.linalg.det(U @ Vt))
    D = np.zeros(U.shape)
    D[..., 0, 0] = 1.0
    D[..., 1, 1] = 1.0
    D[..., 2, 2] = d
    out = np.zeros(T.shape)
    out[..., :3, :3] = U @ D @ Vt
    out[..., :3, 3] = T[..., :3, 3]
    out[..., 3, 3] = 1.0
    return out
