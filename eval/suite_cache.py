"""Simulated scenarios for the evaluation suite, generated once and cached under ``eval/cache/``.

One folder per (scenario, seed, duration): the output of :func:`lidar3d.sim.write_simulation`
(``scans.bag``, ``ground_truth_tum.txt``, ``novatel_span.log``, ``extrinsics.toml``,
``metadata.json``) plus ``ground_truth_dense_tum.txt``, the true lidar pose every 10 ms over the
whole drive, so that a method whose poses describe another instant of the sweep than its start
(KISS-ICP: the end, GenZ-ICP: the middle) is compared with the truth at that instant without
interpolating across a 100 ms gap.

A folder is reused only while its ``cache_key.json`` matches: the scenario, seed, duration, the
lidar3d version and a hash of the simulator's sources. Anything else regenerates it.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import json
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from lidar3d.sim.scenarios import Scenario

REPO = Path(__file__).resolve().parents[1]
DEFAULT_CACHE = REPO / "eval" / "cache"
DENSE_GT_NAME = "ground_truth_dense_tum.txt"
DENSE_GT_PERIOD_NS = 10_000_000
# What the simulator computes with (ray casting, noise, foliage): a bag is simulated again when one of
# them changes, since the same sources and seed then give other points (forest_trail did, 2026-12-07).
SIMULATOR_LIBRARIES = ("numpy", "scipy", "open3d")
KEY_NAME = "cache_key.json"

__all__ = ["DEFAULT_CACHE", "CachedScenario", "cache_folder_name", "ensure_scenario"]


@dataclass(frozen=True, slots=True)
class CachedScenario:
    """Paths and facts of one cached simulation."""

    scenario: str
    seed: int
    duration_s: float | None
    folder: Path
    bag: Path
    ground_truth: Path
    ground_truth_dense: Path
    span_log: Path
    extrinsics: Path
    metadata: dict
    generated: bool

    @property
    def label(self) -> str:
        return f"{self.scenario} (seed {self.seed})"

    @property
    def n_scans(self) -> int:
        return int(self.metadata["n_scans"])

    @property
    def path_length_m(self) -> float:
        return float(self.metadata["path_length_m"])

    @property
    def sim_duration_s(self) -> float:
        return float(self.metadata["duration_s"])

    @property
    def revisit_events(self) -> int:
        return len(self.metadata.get("revisits", []))


def installed_version(name: str) -> str | None:
    """Installed version of the distribution ``name``, or None."""
    try:
        return importlib.metadata.version(name)
    except importlib.metadata.PackageNotFoundError:
        return None


def installed_versions(names: tuple[str, ...]) -> dict[str, str]:
    """``{distribution: version}`` of the installed distributions (``"not installed"`` if absent)."""
    return {name: installed_version(name) or "not installed" for name in names}


def _simulator_fingerprint() -> str:
    digest = hashlib.sha256()
    sim_dir = REPO / "lidar3d" / "sim"
    for path in sorted(sim_dir.glob("*.py")):
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def cache_folder_name(scenario: str, seed: int, duration_s: float | None) -> str:
    """``loop_s0_full`` or ``loop_s0_d10``."""
    span = "full" if duration_s is None else f"d{duration_s:g}"
    return f"{scenario}_s{seed}_{span}"


def _key(scenario: str | Scenario, seed: int, duration_s: float | None) -> dict:
    from lidar3d import __version__

    named = isinstance(scenario, str)
    return {
        "scenario": _name(scenario),
        **({} if named else {"definition": repr(scenario)}),
        "seed": int(seed),
        "duration_s": duration_s,
        "bag_format": "ros1",
        "sensor": "vlp16",
        "lidar3d_version": __version__,
        "simulator_sources": _simulator_fingerprint(),
        "simulator_libraries": installed_versions(SIMULATOR_LIBRARIES),
    }


def _write_dense_ground_truth(sim, path: Path) -> None:
    from lidar3d.io.trajectory_io import write_tum
    from lidar3d.records import Trajectory

    first = int(sim.sweep_start_ns[0])  # the stamps may mark the sweeps' ends
    end = first + int(round(sim.duration_s * 1e9))  # end of the last sweep
    stamps = np.arange(first, end + 1, DENSE_GT_PERIOD_NS, dtype=np.int64)
    write_tum(path, Trajectory(stamps, sim.T_world_lidar_at(stamps)))


def _load(folder: Path, scenario: str, seed: int, duration_s: float | None, generated: bool) -> CachedScenario:
    metadata = json.loads((folder / "metadata.json").read_text(encoding="utf-8"))
    return CachedScenario(
        scenario=scenario,
        seed=seed,
        duration_s=duration_s,
        folder=folder,
        bag=folder / metadata["files"]["bag"],
        ground_truth=folder / metadata["files"]["ground_truth"],
        ground_truth_dense=folder / DENSE_GT_NAME,
        span_log=folder / metadata["files"]["span_log"],
        extrinsics=folder / metadata["files"]["extrinsics"],
        metadata=metadata,
        generated=generated,
    )


def _name(scenario: str | Scenario) -> str:
    return scenario if isinstance(scenario, str) else scenario.name


def ensure_scenario(
    scenario: str | Scenario,
    seed: int = 0,
    duration_s: float | None = None,
    *,
    cache_dir: Path = DEFAULT_CACHE,
    regenerate: bool = False,
) -> CachedScenario:
    """The cached simulation of ``scenario`` (a name, or a :class:`lidar3d.sim.scenarios.Scenario`
    whose whole definition keys the cache), generated first if missing or stale."""
    from lidar3d.sim import Simulation, write_simulation

    name = _name(scenario)
    folder = Path(cache_dir) / cache_folder_name(name, seed, duration_s)
    key = _key(scenario, seed, duration_s)
    key_path = folder / KEY_NAME
    if not regenerate and key_path.is_file():
        try:
            stored = json.loads(key_path.read_text(encoding="utf-8"))
        except json.JSONDecodeError:
            stored = None
        if stored == key and (folder / DENSE_GT_NAME).is_file() and (folder / "metadata.json").is_file():
            return _load(folder, name, seed, duration_s, generated=False)
    if folder.exists():
        shutil.rmtree(folder)
    tmp = folder.with_name(folder.name + ".partial")
    if tmp.exists():
        shutil.rmtree(tmp)
    sim = Simulation(scenario, seed=seed, duration_s=duration_s)
    write_simulation(sim, tmp, bag_format="ros1")
    _write_dense_ground_truth(sim, tmp / DENSE_GT_NAME)
    (tmp / KEY_NAME).write_text(json.dumps(key, indent=1) + "\n", encoding="utf-8")
    tmp.rename(folder)  # the folder appears complete or not at all
    return _load(folder, name, seed, duration_s, generated=True)
