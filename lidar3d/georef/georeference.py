"""The georeference of a run: where the SLAM world frame sits in a local ENU frame on the WGS84 ellipsoid.

``lidar3d run --span LOG`` fits ``T_enu_world`` (SLAM world frame -> local ENU at the log's origin)
from the lidar trajectory and the INS reference poses at the same stamps, moved to the lidar
(``T_enu_lidar = T_enu_imu . T_imu_lidar``), and writes it as ``georef.json``
(:meth:`Georeference.to_json`). Two methods:

* ``yaw`` (default, 4-DoF): gravity is known, so roll and pitch are not fitted to positions. The up
  axis of ENU seen in the world frame is taken from the attitudes, u_i = R_i^T e_z with
  R_i = R_enu_lidar,ref,i R_world_lidar,est,i^T (one estimate of R_enu_world per epoch), averaged and
  normalised; the world is levelled by the smallest rotation taking u to e_z, then yaw and
  translation come in closed form (:func:`lidar3d.metrics.alignment.yaw_alignment`,
  theta = atan2(H01 - H10, H00 + H11)). This stays well posed on a straight drive.
* ``se3``: Umeyama on the positions (:func:`lidar3d.metrics.alignment.umeyama_se3`); on a nearly
  straight path (conditioning below :data:`lidar3d.metrics.alignment.SE3_MIN_CONDITIONING`) it falls
  back to ``yaw`` and says so in ``note``.

The fit is robust to position jumps: after a first fit, epochs whose residual exceeds both
``max_fit_residual_m`` and five times the median residual are dropped and the fit repeated once.
"""

from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lidar3d.errors import GeoreferenceError, GnssError
from lidar3d.gnss.enu import GeodeticOrigin
from lidar3d.gnss.reference import InsReference
from lidar3d.metrics.alignment import SE3_MIN_CONDITIONING, se3_conditioning, umeyama_se3, yaw_alignment
from lidar3d.metrics.association import associate
from lidar3d.metrics.errors import EvaluationError
from lidar3d.records import Trajectory

__all__ = [
    "GEOREF_FORMAT",
    "FitResidual",
    "Georeference",
    "GnssFusionRecord",
    "file_sha256",
    "fit_georeference",
    "held_out_mask",
    "read_georeference",
]

logger = logging.getLogger(__name__)

GEOREF_FORMAT = "lidar3d-georef/1"
_OUTLIER_MEDIAN_FACTOR = 5.0
_MIN_EPOCHS = 3


def file_sha256(path: str | Path) -> str:
    """SHA-256 of a file's bytes, hex; "" when the file cannot be read."""
    digest = hashlib.sha256()
    try:
        with open(path, "rb") as stream:
            for chunk in iter(lambda: stream.read(1 << 20), b""):
                digest.update(chunk)
    except OSError:
        return ""
    return digest.hexdigest()


@dataclass(frozen=True, slots=True)
class FitResidual:
    """Residuals of the fit over the epochs used, metres: |p_ref - T_enu_world p_est|."""

    rmse_m: float
    horizontal_rmse_m: float
    vertical_rmse_m: float
    max_m: float

    @classmethod
    def of(cls, residual_enu_m: np.ndarray) -> FitResidual:
        """From (N, 3) residual vectors (east, north, up)."""
        r = np.asarray(residual_enu_m, float).reshape(-1, 3)
        norm = np.linalg.norm(r, axis=1)
        return cls(
            rmse_m=float(np.sqrt(np.mean(norm**2))),
            horizontal_rmse_m=float(np.sqrt(np.mean(np.sum(r[:, :2] ** 2, axis=1)))),
            vertical_rmse_m=float(np.sqrt(np.mean(r[:, 2] ** 2))),
            max_m=float(norm.max()),
        )


@dataclass(frozen=True, slots=True)
class GnssFusionRecord:
    """What the GNSS position factors of a run used (``lidar3d run --gnss-factors``).

    Attributes:
        span_source: the log fused.
        span_sha256: its SHA-256, so an evaluation can tell that it scores against the same log.
        fused_stamps_ns: (F,) stamps of the keyframes that got a GNSS factor.
        candidates: keyframes with an accepted-status INS solution within the gap.
        rejected_quality: of those, refused for their reported standard deviation.
        rejected_consistency: refused by the consistency test against the odometry (jumps).
        rejected_hold_out: left out because they fall in a held-out period.
        hold_out_period_s: the hold-out period (0: none).
    """

    span_source: str
    span_sha256: str
    fused_stamps_ns: np.ndarray
    candidates: int
    rejected_quality: int
    rejected_consistency: int
    rejected_hold_out: int
    hold_out_period_s: float

    def __post_init__(self) -> None:
        stamps = np.array(self.fused_stamps_ns, dtype=np.int64).reshape(-1)
        stamps.flags.writeable = False
        object.__setattr__(self, "fused_stamps_ns", stamps)

    def held_out(self, stamps_ns: np.ndarray) -> np.ndarray:
        """(N,) bool: which stamps lie in a held-out (odd) period; all False without hold-out."""
        stamps = np.asarray(stamps_ns, dtype=np.int64)
        if self.hold_out_period_s <= 0.0:
            return np.zeros(stamps.shape, dtype=bool)
        return held_out_mask(stamps, self.hold_out_period_s)

    def to_dict(self) -> dict:
        return {
            "span_source": self.span_source,
            "span_sha256": self.span_sha256,
            "fused_epochs": int(len(self.fused_stamps_ns)),
            "fused_stamps_ns": [int(s) for s in self.fused_stamps_ns],
            "candidates": self.candidates,
            "rejected_quality": self.rejected_quality,
            "rejected_consistency": self.rejected_consistency,
            "rejected_hold_out": self.rejected_hold_out,
            "hold_out_period_s": self.hold_out_period_s,
        }

    @classmethod
    def from_dict(cls, data: dict) -> GnssFusionRecord:
        return cls(
            span_source=str(data["span_source"]),
            span_sha256=str(data["span_sha256"]),
            fused_stamps_ns=np.array(data["fused_stamps_ns"], dtype=np.int64),
            candidates=int(data["candidates"]),
            rejected_quality=int(data["rejected_quality"]),
            rejected_consistency=int(data["rejected_consistency"]),
            rejected_hold_out=int(data["rejected_hold_out"]),
            hold_out_period_s=float(data["hold_out_period_s"]),
        )


def held_out_mask(stamps_ns: np.ndarray, period_s: float) -> np.ndarray:
    """(N,) bool: stamps in odd periods, floor(t / period) odd (t in UNIX seconds)."""
    period_ns = int(round(period_s * 1e9))
    return (np.asarray(stamps_ns, dtype=np.int64) // period_ns) % 2 == 1


@dataclass(frozen=True, slots=True)
class Georeference:
    """The SLAM world frame of a run placed in a local ENU frame.

    Attributes:
        origin: WGS84 origin of the ENU frame (ellipsoidal height).
        T_enu_world: (4, 4) float64: SLAM world frame -> ENU (p_enu = T_enu_world p_world).
        method: the method used (``yaw`` or ``se3``); ``method_requested`` the one asked for.
        note: why they differ (one line), else "".
        epochs_used: associated poses the fit used; ``epochs_rejected`` dropped as jumps.
        first_stamp_ns, last_stamp_ns: the span of the epochs used (bag clock).
        residual: fit residuals over the epochs used.
        span_source, span_sha256: the SPAN log and its SHA-256; ``reference_log`` its pose log.
        T_imu_lidar: (4, 4) the extrinsic the reference was moved to the lidar with.
        fusion: what the GNSS factors used, when the run fused the log (else None).
    """

    origin: GeodeticOrigin
    T_enu_world: np.ndarray
    method: str
    method_requested: str
    note: str
    epochs_used: int
    epochs_rejected: int
    first_stamp_ns: int
    last_stamp_ns: int
    residual: FitResidual
    span_source: str
    span_sha256: str
    reference_log: str
    T_imu_lidar: np.ndarray
    fusion: GnssFusionRecord | None = None

    def __post_init__(self) -> None:
        for name in ("T_enu_world", "T_imu_lidar"):
            T = np.array(getattr(self, name), dtype=np.float64)
            if T.shape != (4, 4) or not np.isfinite(T).all():
                raise ValueError(f"Georeference.{name} must be a finite (4, 4) transform")
            T.flags.writeable = False
            object.__setattr__(self, name, T)

    def to_dict(self) -> dict:
        o = self.origin
        return {
            "format": GEOREF_FORMAT,
            "origin": {
                "latitude_deg": o.latitude_deg,
                "longitude_deg": o.longitude_deg,
                "height_ellipsoid_m": o.height_ellipsoid_m,
                "datum": "WGS84",
            },
            "T_enu_world": self.T_enu_world.tolist(),
            "frames": "p_enu = T_enu_world p_world; ENU: x east, y north, z up at the origin; world: the SLAM frame",
            "method": self.method,
            "method_requested": self.method_requested,
            "note": self.note,
            "epochs_used": self.epochs_used,
            "epochs_rejected": self.epochs_rejected,
            "first_stamp_ns": self.first_stamp_ns,
            "last_stamp_ns": self.last_stamp_ns,
            "residual": {
                "rmse_m": self.residual.rmse_m,
                "horizontal_rmse_m": self.residual.horizontal_rmse_m,
                "vertical_rmse_m": self.residual.vertical_rmse_m,
                "max_m": self.residual.max_m,
            },
            "span_source": self.span_source,
            "span_sha256": self.span_sha256,
            "reference_log": self.reference_log,
            "T_imu_lidar": self.T_imu_lidar.tolist(),
            "gnss_factors": None if self.fusion is None else self.fusion.to_dict(),
        }

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2) + "\n"

    @classmethod
    def from_dict(cls, data: dict) -> Georeference:
        """Inverse of :meth:`to_dict`; ``KeyError``/``TypeError``/``ValueError`` on a bad layout."""
        if data.get("format") != GEOREF_FORMAT:
            raise ValueError(f"format {data.get('format')!r} is not {GEOREF_FORMAT!r}")
        o, r = data["origin"], data["residual"]
        fusion = data.get("gnss_factors")
        return cls(
            origin=GeodeticOrigin(o["latitude_deg"], o["longitude_deg"], o["height_ellipsoid_m"]),
            T_enu_world=np.array(data["T_enu_world"], dtype=np.float64),
            method=str(data["method"]),
            method_requested=str(data["method_requested"]),
            note=str(data["note"]),
            epochs_used=int(data["epochs_used"]),
            epochs_rejected=int(data["epochs_rejected"]),
            first_stamp_ns=int(data["first_stamp_ns"]),
            last_stamp_ns=int(data["last_stamp_ns"]),
            residual=FitResidual(
                float(r["rmse_m"]), float(r["horizontal_rmse_m"]), float(r["vertical_rmse_m"]), float(r["max_m"])
            ),
            span_source=str(data["span_source"]),
            span_sha256=str(data["span_sha256"]),
            reference_log=str(data["reference_log"]),
            T_imu_lidar=np.array(data["T_imu_lidar"], dtype=np.float64),
            fusion=None if fusion is None else GnssFusionRecord.from_dict(fusion),
        )


def read_georeference(path: str | Path) -> Georeference:
    """Read ``georef.json``; :class:`GeoreferenceError` (one line) when missing or malformed."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise GeoreferenceError(
            f"{path.parent}: no georef.json: a georeference needs a SPAN log (lidar3d run BAG --span LOG)"
        ) from None
    except OSError as err:
        raise GeoreferenceError(f"{path}: cannot read: {err.strerror or err}") from err
    try:
        return Georeference.from_dict(json.loads(text))
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as err:
        raise GeoreferenceError(f"{path}: not a lidar3d georeference ({type(err).__name__}: {err})") from err
    except GnssError as err:  # an origin outside the usable range
        raise GeoreferenceError(f"{path}: {err}") from err


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking unit vector ``a`` onto unit vector ``b`` (Rodrigues)."""
    v = np.cross(a, b)
    c = float(np.dot(a, b))
    if c < -1.0 + 1e-12:
        raise GeoreferenceError("the SLAM world frame is upside down against the INS attitude")
    vx = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + vx + vx @ vx / (1.0 + c)


def _level_then_yaw(T_enu_lidar: np.ndarray, T_world_lidar: np.ndarray) -> np.ndarray:
    """4-DoF fit: roll/pitch from the attitudes (the mean up axis), yaw and translation from positions."""
    R_enu_world = T_enu_lidar[:, :3, :3] @ np.swapaxes(T_world_lidar[:, :3, :3], 1, 2)
    up_world = R_enu_world[:, 2, :].mean(axis=0)  # row 2 = R^T e_z, the ENU up axis in world coordinates
    up_world /= np.linalg.norm(up_world)
    level = np.eye(4)
    level[:3, :3] = _rotation_between(up_world, np.array([0.0, 0.0, 1.0]))
    levelled = T_world_lidar[:, :3, 3] @ level[:3, :3].T
    return yaw_alignment(levelled, T_enu_lidar[:, :3, 3]) @ level


def _fit(T_enu_lidar: np.ndarray, T_world_lidar: np.ndarray, method: str) -> tuple[np.ndarray, str, str]:
    """(T_enu_world, method used, note) for associated poses."""
    if method == "se3":
        kappa = se3_conditioning(T_enu_lidar[:, :3, 3])
        if kappa >= SE3_MIN_CONDITIONING:
            return umeyama_se3(T_world_lidar[:, :3, 3], T_enu_lidar[:, :3, 3]), "se3", ""
        note = (
            f"se3 fit is ill-conditioned (conditioning {kappa:.1e} < {SE3_MIN_CONDITIONING:g}: the path is nearly "
            "straight); used yaw (roll and pitch from the INS attitude)"
        )
        return _level_then_yaw(T_enu_lidar, T_world_lidar), "yaw", note
    if method != "yaw":
        raise GeoreferenceError(f"unknown georeference method {method!r} (choose yaw or se3)")
    return _level_then_yaw(T_enu_lidar, T_world_lidar), "yaw", ""


def fit_georeference(
    estimate: Trajectory,
    reference: InsReference,
    *,
    T_imu_lidar: np.ndarray | None = None,
    method: str = "yaw",
    max_gap_s: float = 0.2,
    max_fit_residual_m: float = 5.0,
    span_source: str = "",
    span_sha256: str = "",
) -> Georeference:
    """Fit ``T_enu_world`` of ``estimate`` (lidar poses, SLAM world) to the INS ``reference``.

    Args:
        estimate: the run's lidar trajectory, stamps on the reference's clock.
        reference: INS poses in ENU (:func:`lidar3d.gnss.reference.span_reference`), accepted statuses only.
        T_imu_lidar: the lidar pose in the IMU frame (identity if None).
        method: ``yaw`` (4-DoF, default) or ``se3`` (module docstring).
        max_gap_s: longest reference interval interpolated across.
        max_fit_residual_m: jump rejection threshold (module docstring).

    Raises :class:`GeoreferenceError` when fewer than 3 poses overlap the reference.
    """
    T_il = np.eye(4) if T_imu_lidar is None else np.asarray(T_imu_lidar, dtype=np.float64)
    try:
        pairs = associate(estimate, reference.trajectory, max_gap_s)
    except EvaluationError as err:
        raise GeoreferenceError(f"{span_source or 'SPAN log'}: no georeference: {err}") from err
    if len(pairs) < _MIN_EPOCHS:
        raise GeoreferenceError(
            f"{span_source or 'SPAN log'}: no georeference: only {len(pairs)} of {len(estimate)} poses overlap "
            f"the INS solutions (at least {_MIN_EPOCHS} needed)"
        )
    T_enu_lidar = pairs.T_world_reference @ T_il
    T_world_lidar = pairs.T_world_estimate
    keep = np.ones(len(pairs), dtype=bool)
    T, used, note = _fit(T_enu_lidar, T_world_lidar, method)
    residual = T_enu_lidar[:, :3, 3] - (T_world_lidar[:, :3, 3] @ T[:3, :3].T + T[:3, 3])
    norm = np.linalg.norm(residual, axis=1)
    outliers = (norm > max_fit_residual_m) & (norm > _OUTLIER_MEDIAN_FACTOR * np.median(norm))
    if outliers.any() and (~outliers).sum() >= _MIN_EPOCHS:
        keep = ~outliers
        logger.warning(
            "%s: georeference: %d of %d epochs dropped as jumps (residual up to %.1f m)",
            span_source or "SPAN log",
            int(outliers.sum()),
            len(pairs),
            float(norm[outliers].max()),
        )
        T, used, note = _fit(T_enu_lidar[keep], T_world_lidar[keep], method)
        residual = T_enu_lidar[:, :3, 3] - (T_world_lidar[:, :3, 3] @ T[:3, :3].T + T[:3, 3])
    stamps = pairs.stamps_ns[keep]
    return Georeference(
        origin=reference.origin,
        T_enu_world=T,
        method=used,
        method_requested=method,
        note=note,
        epochs_used=int(keep.sum()),
        epochs_rejected=int((~keep).sum()),
        first_stamp_ns=int(stamps[0]),
        last_stamp_ns=int(stamps[-1]),
        residual=FitResidual.of(residual[keep]),
        span_source=span_source,
        span_sha256=span_sha256,
        reference_log=reference.source_log,
        T_imu_lidar=T_il,
    )
