"""SE(3) helpers on 4x4 float64 matrices: exponential/log maps, interpolation, point transforms,
projection of nearly rigid matrices back onto SE(3).

Twists are ordered (v, w): translation part first, rotation part second, in the frame noted by
the caller. Formulas: Barfoot, "State Estimation for Robotics" (2017), eqs. 7.85-7.95.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

__all__ = [
    "cross",
    "exp_apply",
    "exp_se3",
    "interpolate_poses",
    "invert",
    "log_se3",
    "nearest_rigid",
    "pose_from_xyz_rpy",
    "so3_exp",
    "transform_points",
    "xyz_rpy_from_pose",
]


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a 4x4 transform to (N,3) points."""
    return points @ T[:3, :3].T + T[:3, 3]


def invert(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid transform (or a stack (...,4,4) of them)."""
    R = T[..., :3, :3]
    t = T[..., :3, 3]
    out = np.zeros_like(T)
    Rt = np.swapaxes(R, -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, t)
    out[..., 3, 3] = 1.0
    return out


def nearest_rigid(T: np.ndarray) -> np.ndarray:
    """The rigid transform(s) nearest to ``T`` (4,4) or (...,4,4): rotation by SVD (Frobenius-nearest
    rotation, det +1), translation kept, last row (0, 0, 0, 1).

    Why poses are projected: poses that go round the loop-closure cycle (pose-graph estimate ->
    correction -> initial guess -> ICP -> loop factor -> estimate) pick up rounding off SO(3); GTSAM
    keeps a ``Rot3`` built from a matrix as given and its compose/retract amplify the defect (about
    fourfold per closure in our runs, until iSAM2 reports an indeterminant system). Every pose entering
    the pose graph or leaving :mod:`lidar3d.loop` is therefore projected with this function.
    """
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


def _skew(w: np.ndarray) -> np.ndarray:
    """(...,3) -> (...,3,3) cross-product matrices."""
    out = np.zeros(w.shape[:-1] + (3, 3))
    out[..., 0, 1] = -w[..., 2]
    out[..., 0, 2] = w[..., 1]
    out[..., 1, 0] = w[..., 2]
    out[..., 1, 2] = -w[..., 0]
    out[..., 2, 0] = -w[..., 1]
    out[..., 2, 1] = w[..., 0]
    return out


def so3_exp(w: np.ndarray) -> np.ndarray:
    """Rodrigues' formula for a stack of rotation vectors (...,3) -> (...,3,3)."""
    w = np.asarray(w, dtype=np.float64)
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    K = _skew(w)
    small = theta < 1e-9
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0, np.sin(safe) / safe)
    b = np.where(small, 0.5, (1.0 - np.cos(safe)) / safe**2)
    eye = np.broadcast_to(np.eye(3), K.shape)
    return eye + a * K + b * (K @ K)


def _left_jacobian(w: np.ndarray) -> np.ndarray:
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    K = _skew(w)
    small = theta < 1e-9
    safe = np.where(small, 1.0, theta)
    b = np.where(small, 0.5, (1.0 - np.cos(safe)) / safe**2)
    c = np.where(small, 1.0 / 6.0, (safe - np.sin(safe)) / safe**3)
    eye = np.broadcast_to(np.eye(3), K.shape)
    return eye + b * K + c * (K @ K)


def exp_se3(xi: np.ndarray) -> np.ndarray:
    """Exponential map of twists (...,6) ordered (v, w) to transforms (...,4,4)."""
    xi = np.asarray(xi, dtype=np.float64)
    v = xi[..., :3]
    w = xi[..., 3:]
    out = np.zeros(xi.shape[:-1] + (4, 4))
    out[..., :3, :3] = so3_exp(w)
    out[..., :3, 3] = np.einsum("...ij,...j->...i", _left_jacobian(w), v)
    out[..., 3, 3] = 1.0
    return out


def log_se3(T: np.ndarray) -> np.ndarray:
    """Logarithm of a single transform: twist (6,) ordered (v, w)."""
    w = Rotation.from_matrix(T[:3, :3]).as_rotvec()
    J = _left_jacobian(w)
    v = np.linalg.solve(J, T[:3, 3])
    return np.concatenate([v, w])


def interpolate_poses(stamps_ns: np.ndarray, poses: np.ndarray, query_ns: np.ndarray) -> np.ndarray:
    """Poses at ``query_ns`` by linear translation and spherical rotation interpolation.

    Queries outside the stamps are clamped to the first/last pose.
    """
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    query = np.asarray(query_ns, dtype=np.int64)
    if len(stamps) == 1:
        return np.repeat(poses[:1], len(query), axis=0)
    idx = np.clip(np.searchsorted(stamps, query, side="right") - 1, 0, len(stamps) - 2)
    t0 = stamps[idx]
    t1 = stamps[idx + 1]
    alpha = np.clip((query - t0) / (t1 - t0), 0.0, 1.0)
    R0 = poses[idx, :3, :3]
    R1 = poses[idx + 1, :3, :3]
    delta = Rotation.from_matrix(np.swapaxes(R0, 1, 2) @ R1).as_rotvec()
    out = np.zeros((len(query), 4, 4))
    out[:, :3, :3] = R0 @ so3_exp(delta * alpha[:, None])
    out[:, :3, 3] = poses[idx, :3, 3] * (1 - alpha[:, None]) + poses[idx + 1, :3, 3] * alpha[:, None]
    out[:, 3, 3] = 1.0
    return out


def pose_from_xyz_rpy(x: np.ndarray) -> np.ndarray:
    """(6,) [x, y, z, roll, pitch, yaw] (rad, R = Rz(yaw) Ry(pitch) Rx(roll)) -> 4x4."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", x[3:6]).as_matrix()
    T[:3, 3] = x[:3]
    return T


def xyz_rpy_from_pose(T: np.ndarray) -> np.ndarray:
    """Inverse of :func:`pose_from_xyz_rpy`."""
    return np.concatenate([T[:3, 3], Rotation.from_matrix(T[:3, :3]).as_euler("xyz")])


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise cross product of (N,3) arrays (np.cross is several times slower on small arrays)."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


def exp_apply(twist: np.ndarray, times: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply ``exp_se3(times[i] * twist)`` to ``points[i]`` for every i (one twist (v, w), (N,)
    scalings), without forming (N,4,4) matrices.

    Every point turns about the same unit axis k = w/|w|, by its own angle theta_i = t_i |w|, so
    Rodrigues' formula becomes two (N,3)x(3,3) products with the constant matrices [k]x and
    [k]x^2, and the left Jacobian on v a sum of three constant vectors with per-point weights:
    R_i p = p + sin(theta_i) [k]x p + (1 - cos(theta_i)) [k]x^2 p,
    J_i (t_i v) = t_i v + t_i (1 - cos(theta_i)) / theta_i [k]x v + t_i (theta_i - sin(theta_i)) / theta_i [k]x^2 v.
    This is the deskewing hot path (every sweep, several times).
    """
    twist = np.asarray(twist, dtype=np.float64)
    times = np.asarray(times, dtype=np.float64)
    v, w = twist[:3], twist[3:]
    speed = float(np.linalg.norm(w))
    if speed < 1e-12:
        return points + times[:, None] * v
    K = _skew(w / speed)
    K2 = K @ K
    theta = times * speed
    sin, cos = np.sin(theta), np.cos(theta)
    rotated = points + sin[:, None] * (points @ K.T) + (1.0 - cos)[:, None] * (points @ K2.T)
    # (1 - cos)/theta * t = (1 - cos)/|w|, (theta - sin)/theta * t = (theta - sin)/|w|: no division by theta.
    translated = (
        times[:, None] * v + ((1.0 - cos) / speed)[:, None] * (K @ v) + ((theta - sin) / speed)[:, None] * (K2 @ v)
    )
    return rotated + translated
