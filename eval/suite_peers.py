"""Peer odometries for the evaluation suite: KISS-ICP and GenZ-ICP, driven through their Python APIs.

Both peers are optional evaluation dependencies (``pip install -e ".[eval]"``). They read the same
bag as lidar3d, through :class:`lidar3d.io.scan_source.ScanSource`, and get every point of each scan
with its firing time normalised to 0..1 over the sweep ((t - t_min) / (t_max - t_min)):

* **KISS-ICP** (defaults: max range 100 m, voxel 1 m). Its deskew moves every point to the time
  of the sweep's *last* point (since KISS-ICP 1.2, PR #412/#427), so its pose i is the lidar pose at
  ``stamp_i + t_max``, not at the header stamp (sweep start) that our trajectory and the ground
  truth use.
* **GenZ-ICP** (``outdoor`` preset, deskew switched on). Its deskewer expects times in 0..1 and
  deskews to the *middle* of the sweep (``mid_pose_timestamp = 0.5`` in ``Deskew.cpp``); its
  command-line tool hands it the VLP-16 ``time`` field in seconds (0..0.1), which makes the
  deskew correction ten times too small, silently. Its pose i is the pose at
  ``stamp_i + (t_min + t_max) / 2``.

Which instant a peer's pose refers to is not assumed from its version: :func:`deskew_reference_fraction`
probes the installed preprocessor with a known motion and finds the sweep fraction it deskews to.
Each peer's poses are then stamped at that instant, and the evaluation interpolates the reference
there (the association in :mod:`lidar3d.metrics`), so every method is compared with the reference
at the instant its own poses describe.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np
from suite_cache import installed_version

__all__ = [
    "PEERS",
    "PeerRun",
    "PeerUnavailable",
    "deskew_reference_fraction",
    "normalised_times",
    "run_peer",
]

#: display names of the peers, in table order
PEERS: dict[str, str] = {"kiss-icp": "KISS-ICP", "genz-icp": "GenZ-ICP"}

#: sweep fraction a pose refers to when the peer does not deskew (the cloud is registered as it was
#: recorded, so the estimate is the pose of the sweep's centre in time)
UNDESKEWED_FRACTION = 0.5


class PeerUnavailable(RuntimeError):
    """A peer package is not installed (install the ``eval`` extra)."""


@dataclass(frozen=True, slots=True)
class PeerRun:
    """What one peer produced on one bag.

    Attributes:
        stamps_ns: (N,) stamp of each pose: the instant within the sweep the peer's pose describes.
        header_stamps_ns: (N,) header stamp (sweep start) of the scan each pose came from.
        T_world_lidar: (N, 4, 4) the peer's poses (its own world frame: the first pose is identity).
        register_ms: (N,) wall time of ``register_frame`` per scan.
        read_ms: (N,) wall time of reading and decoding each scan from the bag.
        wall_s: wall time of the whole loop (reading + conversion + registration).
        reference_fraction: sweep fraction (0 start, 1 end) the poses refer to.
        settings: the peer's resolved configuration and version, for the record.
    """

    stamps_ns: np.ndarray
    header_stamps_ns: np.ndarray
    T_world_lidar: np.ndarray
    register_ms: np.ndarray
    read_ms: np.ndarray
    wall_s: float
    reference_fraction: float
    settings: dict = field(default_factory=dict)


def normalised_times(time_offset_s: np.ndarray) -> np.ndarray:
    """Per-point times scaled to 0..1 over the sweep; a sweep of one instant is all 0."""
    t = np.asarray(time_offset_s, dtype=np.float64)
    if t.size == 0:
        return t
    lo, hi = float(t.min()), float(t.max())
    if hi <= lo:
        return np.zeros_like(t)
    return (t - lo) / (hi - lo)


def deskew_reference_fraction(preprocess: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]) -> float:
    """Sweep fraction in 0..1 that ``preprocess(points, times01, relative_motion)`` deskews to.

    Three copies of one point, stamped 0, 0.5 and 1, are deskewed under a 1 m forward motion per
    sweep: a copy stamped t moves by (t - t_ref) metres, so t_ref is where the motion would be zero.
    Returns :data:`UNDESKEWED_FRACTION` when nothing moves (deskew switched off). For GenZ-ICP the
    probe calls the native preprocessor that its Python wrapper is built on (``genz_icp_pybind``),
    as the wrapper exposes no preprocessing step of its own.
    """
    points = np.array([[10.0, 0.0, 0.0]] * 3)
    times = np.array([0.0, 0.5, 1.0])
    motion = np.eye(4)
    motion[0, 3] = 1.0
    out = np.asarray(preprocess(points, times, motion), dtype=np.float64)
    if out.shape != points.shape:
        raise RuntimeError(f"deskew probe: preprocessor returned shape {out.shape}, expected {points.shape}")
    dx = out[:, 0] - points[:, 0]
    if np.all(np.abs(out - points) < 1e-9):
        return UNDESKEWED_FRACTION
    # a point stamped t moves by (t - t_ref) x 1 m along x under this motion
    return float(np.clip(np.median(times - dx), 0.0, 1.0))


# --- the peers -------------------------------------------------------------------------------------


class _Odometry(Protocol):
    """One peer behind one verb: ``register(points, times01) -> T_world_lidar``."""

    name: str
    reference_fraction: float
    settings: dict

    def register(self, points: np.ndarray, times01: np.ndarray) -> np.ndarray: ...


class _KissIcp:
    name = "kiss-icp"

    def __init__(self) -> None:
        try:
            from kiss_icp.config import load_config
            from kiss_icp.kiss_icp import KissICP
            from kiss_icp.preprocess import get_preprocessor
        except ImportError as err:
            raise PeerUnavailable(f"kiss-icp is not installed ({err}); pip install -e '.[eval]'") from err
        config = load_config(None)  # the library defaults, voxel size derived from max range
        self._odometry = KissICP(config)
        probe = get_preprocessor(config)
        self.reference_fraction = deskew_reference_fraction(probe.preprocess)
        self.settings = {
            "version": installed_version("kiss-icp"),
            "config": config.model_dump(),
            "preset": "library defaults",
        }

    def register(self, points: np.ndarray, times01: np.ndarray) -> np.ndarray:
        self._odometry.register_frame(points, times01)
        return np.asarray(self._odometry.last_pose, dtype=np.float64)


class _GenzIcp:
    name = "genz-icp"

    def __init__(self, *, preset: str = "outdoor", deskew: bool = True) -> None:
        try:
            from genz_icp.config import load_config
            from genz_icp.genz_icp import GenZICP
            from genz_icp.pybind import genz_icp_pybind
        except ImportError as err:
            raise PeerUnavailable(f"genz-icp is not installed ({err}); pip install -e '.[eval]'") from err
        config = load_config(Path(preset))  # resolved among the package's pre-tuned presets
        config.data.deskew = bool(deskew)
        self._odometry = GenZICP(config)
        native = genz_icp_pybind._Preprocessor(config.data.max_range, 0.0, config.data.deskew, 1)

        def preprocess(points: np.ndarray, times: np.ndarray, motion: np.ndarray) -> np.ndarray:
            return np.asarray(native._preprocess(genz_icp_pybind._Vector3dVector(points), list(times), motion))

        self.reference_fraction = deskew_reference_fraction(preprocess)
        self.settings = {
            "version": installed_version("genz-icp"),
            "config": config.model_dump(),
            "preset": preset,
            "deskew": bool(deskew),
        }

    def register(self, points: np.ndarray, times01: np.ndarray) -> np.ndarray:
        self._odometry.register_frame(points, times01)
        return np.asarray(self._odometry.last_pose, dtype=np.float64)


def make_peer(name: str, *, genz_deskew: bool = True) -> _Odometry:
    """A fresh odometry of the named peer (``kiss-icp`` or ``genz-icp``)."""
    if name == "kiss-icp":
        return _KissIcp()
    if name == "genz-icp":
        return _GenzIcp(deskew=genz_deskew)
    raise ValueError(f"unknown peer {name!r}; known: {', '.join(PEERS)}")


def _timed_scans(bag: Path) -> Iterator[tuple[object, float]]:
    from lidar3d.io.scan_source import ScanSource

    with ScanSource(bag) as source:
        scans = iter(source)
        while True:
            t0 = time.perf_counter()
            scan = next(scans, None)
            if scan is None:
                return
            yield scan, (time.perf_counter() - t0) * 1e3


def run_peer(
    name: str,
    bag: str | Path,
    *,
    max_scans: int | None = None,
    genz_deskew: bool = True,
    on_scan: Callable[[int], None] | None = None,
) -> PeerRun:
    """Run peer ``name`` over every scan of ``bag`` (or the first ``max_scans``)."""
    odometry = make_peer(name, genz_deskew=genz_deskew)
    stamps: list[int] = []
    headers: list[int] = []
    poses: list[np.ndarray] = []
    register_ms: list[float] = []
    read_ms: list[float] = []
    fraction = odometry.reference_fraction
    t_start = time.perf_counter()
    for scan, read in _timed_scans(Path(bag)):
        if max_scans is not None and len(poses) >= max_scans:
            break
        offsets = scan.time_offset_s
        lo, hi = (float(offsets.min()), float(offsets.max())) if offsets.size else (0.0, 0.0)
        times01 = normalised_times(offsets)
        t0 = time.perf_counter()
        pose = odometry.register(np.array(scan.points, dtype=np.float64), times01)  # peers need writeable arrays
        register_ms.append((time.perf_counter() - t0) * 1e3)
        read_ms.append(read)
        headers.append(scan.stamp_ns)
        stamps.append(scan.stamp_ns + int(round((lo + fraction * (hi - lo)) * 1e9)))
        poses.append(pose)
        if on_scan is not None:
            on_scan(len(poses))
    wall_s = time.perf_counter() - t_start
    return PeerRun(
        stamps_ns=np.asarray(stamps, dtype=np.int64),
        header_stamps_ns=np.asarray(headers, dtype=np.int64),
        T_world_lidar=np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4),
        register_ms=np.asarray(register_ms),
        read_ms=np.asarray(read_ms),
        wall_s=wall_s,
        reference_fraction=fraction,
        settings=odometry.settings,
    )
