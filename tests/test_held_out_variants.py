"""The held-out variants of ``eval/held_out.py``: each is a valid drive that differs from its base."""

import dataclasses
import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "eval"))
held_out = pytest.importorskip("held_out")
suite_cache = pytest.importorskip("suite_cache")

from lidar3d.sim import Simulation  # noqa: E402
from lidar3d.sim.scenarios import SCENARIOS  # noqa: E402


@pytest.mark.parametrize("name", sorted(held_out.VARIANTS))
def test_a_variant_keeps_its_layout_and_changes_the_drive(name):
    variant = held_out.variant_scenario(name)
    base = SCENARIOS[held_out.VARIANTS[name][0]]
    assert variant.name == name and variant.layout == base.layout and variant.route_m == base.route_m
    assert (variant.route, variant.lidar) != (base.route, base.lidar)


def test_a_variant_drives_at_its_own_speeds():
    """``fast15`` is driven faster than ``fast`` ever is: the change reaches the trajectory."""
    fast = Simulation("fast", seed=10, duration_s=20.0).ground_truth
    fast15 = Simulation(held_out.variant_scenario("fast15"), seed=10, duration_s=20.0).ground_truth

    def top_speed(trajectory):
        steps = np.linalg.norm(np.diff(trajectory.positions_m, axis=0), axis=1)
        return float(np.max(steps / (np.diff(trajectory.stamps_ns) * 1e-9)))

    assert top_speed(fast) < 10.5 < 12.0 < top_speed(fast15)  # lidar speed: the IMU's plus a turn's lever


def test_the_cache_is_keyed_by_the_whole_definition(tmp_path):
    variant = held_out.variant_scenario("f8_var")
    first = suite_cache.ensure_scenario(variant, 10, duration_s=0.3, cache_dir=tmp_path)
    assert first.generated and first.scenario == "f8_var" and first.bag.is_file()
    assert not suite_cache.ensure_scenario(variant, 10, duration_s=0.3, cache_dir=tmp_path).generated
    changed = dataclasses.replace(variant, route=dataclasses.replace(variant.route, cruise_speed_mps=7.5))
    again = suite_cache.ensure_scenario(changed, 10, duration_s=0.3, cache_dir=tmp_path)
    assert again.generated
    assert "7.5" in json.loads((again.folder / suite_cache.KEY_NAME).read_text())["definition"]


def test_a_bag_is_simulated_again_when_a_library_of_the_simulator_changes(tmp_path, monkeypatch):
    """The same sources and seed give other points with another numpy or open3d (forest_trail's foliage
    did): the cache holds the versions and does not serve a bag made with others."""
    first = suite_cache.ensure_scenario("loop", 0, duration_s=0.3, cache_dir=tmp_path)
    key = json.loads((first.folder / suite_cache.KEY_NAME).read_text())
    assert set(key["simulator_libraries"]) == set(suite_cache.SIMULATOR_LIBRARIES)
    assert not suite_cache.ensure_scenario("loop", 0, duration_s=0.3, cache_dir=tmp_path).generated
    installed = suite_cache.installed_versions
    monkeypatch.setattr(suite_cache, "installed_versions", lambda names: {**installed(names), "open3d": "0.0.0-other"})
    again = suite_cache.ensure_scenario("loop", 0, duration_s=0.3, cache_dir=tmp_path)
    assert again.generated
    libraries = json.loads((again.folder / suite_cache.KEY_NAME).read_text())["simulator_libraries"]
    assert libraries["open3d"] == "0.0.0-other"
