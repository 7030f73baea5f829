import pytest

from lidar3d.cli.main import main
from lidar3d.config import Config, config_to_toml, load_config
from lidar3d.errors import ConfigError


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
