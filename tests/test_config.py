import importlib.util
import re
from pathlib import Path

import pytest

from lidar3d.cli.main import main
from lidar3d.config import (
    Config,
    ListRange,
    Range,
    config_from_dict,
    config_to_toml,
    config_with,
    key_specs,
    load_config,
)
from lidar3d.errors import ConfigError

ROOT = Path(__file__).resolve().parent.parent


def test_defaults_round_trip_through_toml(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text(config_to_toml(Config()))
    assert load_config(path) == Config()


def test_partial_override_and_int_to_float(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text("[segmentation]\ncluster_angle_deg = 45\n[sensor]\nmodel = 'hdl32e'\n")
    config = load_config(path)
    assert config.segmentation.cluster_angle_deg == 45.0
    assert config.sensor.resolved_model.n_rings == 32
    assert config.features == Config().features


def test_unknown_key_names_dotted_path(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text("[segmentation]\nclustr_angle_deg = 45\n")
    with pytest.raises(ConfigError, match=r"unknown key 'segmentation\.clustr_angle_deg'"):
        load_config(path)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (
            "[loop]\nnormal_radius_m = 1.2\n",
            r"key 'loop\.normal_radius_m' is gone; it is replaced by loop\.icp_neighbours",
        ),
        ("[mapping]\ndegeneracy_threshold = 30\n", r"key 'mapping\.degeneracy_threshold' is gone; .*\[motion\]"),
        ("[health]\ndegraded_after_m = 2.0\n", r"key 'health\.degraded_after_m' is gone; .*health\.degraded_sigma_m"),
    ],
)
def test_a_retired_key_names_its_replacement(tmp_path, text, message):
    path = tmp_path / "c.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_config(path)


def test_unknown_section(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text("[segmentaton]\n")
    with pytest.raises(ConfigError, match="unknown key 'segmentaton'"):
        load_config(path)


def test_wrong_type_names_path(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text("[features]\nsharp_per_section = 2.5\n")
    with pytest.raises(ConfigError, match=r"features\.sharp_per_section: expected an integer"):
        load_config(path)


def test_unknown_sensor_model(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text("[sensor]\nmodel = 'os1'\n")
    with pytest.raises(ConfigError, match=r"sensor\.model"):
        load_config(path)


def test_cli_config_prints_defaults(capsys):
    assert main(["config"]) == 0
    out = capsys.readouterr().out
    assert "[segmentation]" in out and "cluster_angle_deg = 60.0" in out


def test_cli_config_bad_file_one_line(tmp_path, capsys):
    path = tmp_path / "bad.toml"
    path.write_text("[sensor]\nbogus = 1\n")
    assert main(["config", "--config", str(path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.toml" in err[0] and "sensor.bogus" in err[0]


def test_sensor_overrides_resolve_and_round_trip(tmp_path):
    preset = Config().sensor.resolved_model
    assert (preset.name, preset.n_rings, preset.n_columns, preset.rotation_hz, preset.max_range_m) == (
        "vlp16",
        16,
        1800,
        10.0,
        100.0,
    )
    path = tmp_path / "c.toml"
    path.write_text("[sensor]\nmax_range_override_m = 80\nn_columns_override = 900\n")
    config = load_config(path)
    resolved = config.sensor.resolved_model
    assert (resolved.max_range_m, resolved.n_columns, resolved.rotation_hz) == (80.0, 900, 10.0)
    assert resolved.elevation_deg == preset.elevation_deg
    text = config_to_toml(config)
    assert "# vlp16, 16 rings -15.0..15.0 deg, 900 columns, 10.0 Hz, max range 80.0 m" in text
    path.write_text(text)
    assert load_config(path) == config


# -- ranges ------------------------------------------------------------------------------------


def _spec_items():
    return [spec for _section, specs in key_specs() for spec in specs]


def _write(tmp_path, text):
    path = tmp_path / "c.toml"
    path.write_text(text)
    return path


def test_every_numeric_key_has_a_range_and_a_meaning():
    for spec in _spec_items():
        assert spec.meaning, spec.path
        numeric = isinstance(spec.default, (int, float)) and not isinstance(spec.default, bool)
        numbers = isinstance(spec.default, tuple) and spec.valid_text() != "list of strings"
        if numeric:
            assert isinstance(spec.valid, Range), spec.path
        if numbers:
            assert isinstance(spec.valid, ListRange), spec.path


def test_defaults_are_inside_their_ranges():
    """Each default, written out explicitly, passes the loader and gives the defaults back."""
    for spec in _spec_items():
        section, key = spec.path.split(".")
        assert config_from_dict({section: {key: spec.default}}) == Config(), spec.path
        if isinstance(spec.valid, Range):
            assert spec.valid.contains(spec.default), spec.path


# Defect 6 of issue 21: these ran (or crashed with a traceback) instead of being refused.
OUT_OF_RANGE = {
    "mapping.map_voxel_m": (-0.2, r"-0\.2 is out of range \(0, 10\] m"),
    "mapping.corner_voxel_m": (-0.2, r"-0\.2 is out of range \(0, 10\] m"),
    "mapping.surf_voxel_m": (-0.4, r"-0\.4 is out of range \(0, 10\] m"),
    "mapping.scan_surf_voxel_m": (0, r"0\.0 is out of range \(0, 10\] m"),
    "features.less_flat_voxel_m": (-0.2, r"-0\.2 is out of range \(0, 10\] m"),
    "loop.voxel_m": (-0.4, r"-0\.4 is out of range \(0, 10\] m"),
    "sensor.max_range_override_m": (-5, r"-5\.0 is out of range 0 \(preset\) or \(0, 2000\] m"),
    "sensor.n_columns_override": (-1800, r"-1800 is out of range 0 \(preset\) or \[16, 36000\]"),
    "odometry.max_iterations": (0, r"0 is out of range \[1, 1000\]"),
    "mapping.level_normal_z": (1.5, r"1\.5 is out of range \[0, 1\]"),
    "loop.min_fitness": (-0.1, r"-0\.1 is out of range \[0, 1\]"),
    "segmentation.cluster_angle_deg": (90, r"90\.0 is out of range \(0, 90\) deg"),
    "gnss.leap_seconds": (-18, r"-18 is out of range \[0, 100\] s"),
}


@pytest.mark.parametrize("dotted", sorted(OUT_OF_RANGE))
def test_out_of_range_is_one_line_naming_key_value_and_range(dotted, tmp_path, capsys):
    value, message = OUT_OF_RANGE[dotted]
    section, key = dotted.split(".")
    path = _write(tmp_path, f"[{section}]\n{key} = {value}\n")
    with pytest.raises(ConfigError, match=rf"c\.toml: config {re.escape(dotted)}: {message}$"):
        load_config(path)
    assert main(["run", str(tmp_path / "no.bag"), "--out", str(tmp_path / "out"), "--config", str(path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and dotted in err[0] and "Traceback" not in err[0]
    assert not (tmp_path / "out").exists()


def test_map_voxel_flag_and_file_give_the_same_message(tmp_path, capsys):
    path = _write(tmp_path, "[mapping]\nmap_voxel_m = -0.2\n")
    args = ["run", str(tmp_path / "no.bag"), "--out", str(tmp_path / "out")]
    assert main([*args, "--config", str(path)]) == 1
    from_file = capsys.readouterr().err.strip()
    assert main([*args, "--map-voxel", "-0.2"]) == 1
    from_flag = capsys.readouterr().err.strip()
    message = "config mapping.map_voxel_m: -0.2 is out of range (0, 10] m"
    assert from_file == f"lidar3d run: error: {path}: {message}"
    assert from_flag == f"lidar3d run: error: --map-voxel: {message}"
    assert main([*args, "--map-voxel", "nan"]) == 1  # was accepted: nan <= 0 is false
    assert "expected a finite number, got nan" in capsys.readouterr().err


def test_eval_flags_are_checked_like_the_config(tmp_path, capsys):
    args = ["eval", str(tmp_path / "t.txt"), "--span", str(tmp_path / "s.log"), "--out", str(tmp_path / "o")]
    assert main([*args, "--origin", "91", "8.4", "100"]) == 1
    assert capsys.readouterr().err.strip() == (
        "lidar3d eval: error: --origin: config gnss.origin[0] (latitude_deg): 91.0 is out of range [-90, 90] deg"
    )
    assert main([*args, "--time-offset", "1e10"]) == 1
    assert "--time-offset: config gnss.time_offset_s: 10000000000.0 is out of range" in capsys.readouterr().err


def test_config_with_validates_and_replaces():
    config = config_with(Config(), {"mapping": {"map_voxel_m": 0.5}, "input": {"topic": "/points"}})
    assert (config.mapping.map_voxel_m, config.input.topic) == (0.5, "/points")
    assert config.mapping.corner_voxel_m == Config().mapping.corner_voxel_m
    with pytest.raises(ConfigError, match=r"^config mapping\.map_voxel_m: -1\.0 is out of range"):
        config_with(config, {"mapping": {"map_voxel_m": -1.0}})
    with pytest.raises(ConfigError, match=r"unknown key 'mapping\.voxel'"):
        config_with(config, {"mapping": {"voxel": 1.0}})


RELATIONS = {
    "elevations not ascending": (
        "[sensor]\nelevation_override_deg = [-10.0, 5.0, 5.0]\n",
        r"sensor\.elevation_override_deg\[2\]: 5\.0 is not above the entry before it \(5\.0\)",
    ),
    "one elevation": ("[sensor]\nelevation_override_deg = [0.0]\n", r"a list of 1 is out of range \[\] \(preset\)"),
    "elevation beyond 90": (
        "[sensor]\nelevation_override_deg = [0.0, 95.0]\n",
        r"sensor\.elevation_override_deg\[1\]: 95\.0 is out of range \[-90, 90\] deg",
    ),
    "min range above the preset's max": (
        "[sensor]\nmin_range_m = 150\n",
        r"sensor\.min_range_m: 150\.0 is not below the maximum range 100\.0 m",
    ),
    "min range above the override": (
        "[sensor]\nmin_range_m = 5\nmax_range_override_m = 5\n",
        r"sensor\.min_range_m: 5\.0 is not below the maximum range 5\.0 m",
    ),
    "ground rows beyond the rings": (
        "[segmentation]\nground_rows = 17\n",
        r"segmentation\.ground_rows: 17 exceeds the 16 rings of vlp16",
    ),
    "sharp above less sharp": (
        "[features]\nsharp_per_section = 21\n",
        r"features\.sharp_per_section: 21 exceeds features\.less_sharp_per_section \(20\)",
    ),
    "origin of two numbers": ("[gnss]\norigin = [48.1, 11.5]\n", r"gnss\.origin: a list of 2 is out of range"),
    "no ICP stage": ("[loop]\nicp_max_correspondence_m = []\n", r"loop\.icp_max_correspondence_m: a list of 0"),
    "negative ICP stage": (
        "[loop]\nicp_max_correspondence_m = [1.0, -0.5]\n",
        r"loop\.icp_max_correspondence_m\[1\]: -0\.5 is out of range \(0, 100\] m",
    ),
    "unknown alignment": ("[gnss]\nalign = 'affine'\n", r"gnss\.align: 'affine' is not one of se3, yaw, none"),
    "huge integer": ("[mapping]\nmap_voxel_m = 1" + "0" * 40 + "\n", r"an integer of 41 digits is out of any range"),
    "deep nesting": ("[gnss]\norigin = " + "[" * 2000 + "]" * 2000 + "\n", r"nested too deeply"),
}


@pytest.mark.parametrize("case", sorted(RELATIONS))
def test_cross_field_rules_and_lists(case, tmp_path):
    text, message = RELATIONS[case]
    with pytest.raises(ConfigError, match=message) as raised:
        load_config(_write(tmp_path, text))
    assert "\n" not in str(raised.value)


def test_legitimate_extremes_are_accepted(tmp_path):
    """Long-range sensor, handheld recording, a city: unusual values inside the ranges load."""
    text = (
        "[sensor]\nmax_range_override_m = 1000\nmin_range_m = 0.3\nn_columns_override = 4096\n"
        "rotation_override_hz = 20\nelevation_override_deg = [-22.5, -7.5, 7.5, 22.5]\nmount_roll_deg = 180\n"
        "[mapping]\nkeyframe_distance_m = 0\nsubmap_radius_m = 500\n"
        "map_voxel_m = 5\nrobust_scale_m = 0\nlevel_normal_z = 0\n"
        "[loop]\nsearch_radius_m = 50\nmin_time_gap_s = 3600\nicp_max_correspondence_m = [2.0]\n"
        "[gnss]\ntime_offset_s = -1.7e9\norigin = [-33.9, 151.2, -20]\nrpe_distances_m = []\n"
    )
    config = load_config(_write(tmp_path, text))
    assert config.sensor.resolved_model.max_range_m == 1000.0 and config.sensor.resolved_model.n_rings == 4
    assert load_config(_write(tmp_path, config_to_toml(config))) == config


def test_toml_output_gives_each_range_as_a_comment():
    text = config_to_toml(Config())
    assert "map_voxel_m = 0.2  # (0, 10] m\n" in text
    assert "n_columns_override = 0  # 0 (preset) or [16, 36000]\n" in text
    assert 'model = "vlp16"  # vlp16, hdl32e, vlp32c\n' in text
    for spec in _spec_items():
        if isinstance(spec.valid, (Range, ListRange)):
            key = spec.path.split(".")[1]
            assert f"\n{key} = {spec.default_text()}  # {spec.valid}\n" in text, spec.path


def test_manual_tables_match_the_metadata():
    """docs/commands/config.md holds the key tables as scripts/config_reference.py writes them."""
    spec = importlib.util.spec_from_file_location("config_reference", ROOT / "scripts" / "config_reference.py")
    reference = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(reference)
    page = reference.DOC_PATH.read_text(encoding="utf-8")
    assert page == reference.replace_tables(page), "run: python scripts/config_reference.py --write"
    for spec_ in _spec_items():
        assert f"| `{spec_.path.split('.')[1]}` |" in page, spec_.path


def test_strings_with_control_characters_round_trip(tmp_path):
    """Found by the fuzz test: a topic holding a newline or control byte was written as invalid TOML."""
    config = load_config(_write(tmp_path, '[input]\ntopic = "/a\\nb\\u0001\\"c\\\\"\n'))
    assert config.input.topic == '/a\nb\x01"c\\'
    assert load_config(_write(tmp_path, config_to_toml(config))) == config
