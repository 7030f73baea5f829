"""The T_imu_lidar extrinsic file: TOML or YAML, quaternion or roll/pitch/yaw."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lidar3d.errors import GnssError
from lidar3d.gnss import read_extrinsic, write_extrinsic

# lidar x (forward) along the SPAN vehicle's y (forward): a +90 deg yaw
EXPECTED = np.array([[0.0, -1.0, 0.0, 0.1], [1.0, 0.0, 0.0, 0.3], [0.0, 0.0, 1.0, 0.8], [0, 0, 0, 1.0]])


@pytest.mark.parametrize(
    "name,text",
    [
        (
            "q.toml",
            "[T_imu_lidar]\ntranslation_m = [0.1, 0.3, 0.8]\n"
            "quaternion_xyzw = [0.0, 0.0, 0.7071067811865476, 0.7071067811865476]\n",
        ),
        ("r.toml", "[T_imu_lidar]\ntranslation_m = [0.1, 0.3, 0.8]\nrpy_deg = [0, 0, 90]\n"),
        (
            "q.yaml",
            "T_imu_lidar:\n  translation_m: [0.1, 0.3, 0.8]\n"
            "  quaternion_xyzw: [0.0, 0.0, 0.7071067811865476, 0.7071067811865476]\n",
        ),
        ("r.yml", "# comment\nT_imu_lidar:\n  translation_m: [0.1, 0.3, 0.8]\n  rpy_deg: [0.0, 0.0, 90.0]\n"),
    ],
)
def test_formats_give_the_same_transform(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    assert np.allclose(read_extrinsic(path), EXPECTED, atol=1e-12)


def test_rpy_is_fixed_axis_xyz(tmp_path):
    path = tmp_path / "e.toml"
    path.write_text("[T_imu_lidar]\ntranslation_m = [0, 0, 0]\nrpy_deg = [10, -20, 30]\n")
    Rx = Rotation.from_rotvec([np.radians(10), 0, 0]).as_matrix()
    Ry = Rotation.from_rotvec([0, np.radians(-20), 0]).as_matrix()
    Rz = Rotation.from_rotvec([0, 0, np.radians(30)]).as_matrix()
    assert np.allclose(read_extrinsic(path)[:3, :3], Rz @ Ry @ Rx, atol=1e-12)


def test_write_read_round_trip(tmp_path):
    T = np.eye(4)
    T[:3, :3] = Rotation.random(random_state=5).as_matrix()
    T[:3, 3] = [0.12, -0.5, 1.25]
    write_extrinsic(tmp_path / "x.toml", T)
    assert np.allclose(read_extrinsic(tmp_path / "x.toml"), T, atol=1e-12)


@pytest.mark.parametrize(
    "name,text,message",
    [
        ("a.toml", "[T_imu_lidar]\ntranslation_m = [0, 0, 0]\n", "exactly one of quaternion_xyzw"),
        (
            "b.toml",
            "[T_imu_lidar]\ntranslation_m = [0, 0, 0]\nrpy_deg = [0, 0, 0]\nquaternion_xyzw = [0, 0, 0, 1]\n",
            "exactly one of",
        ),
        ("c.toml", "[T_imu_lidar]\ntranslation_m = [0, 0, 0]\nquaternion_xyzw = [0, 0, 0, 2]\n", "unit quaternion"),
        ("d.toml", "[T_imu_lidar]\ntranslation_m = [0, 0]\nrpy_deg = [0, 0, 0]\n", r"translation_m must be 3"),
        ("e.toml", "[lidar]\n", "no T_imu_lidar table"),
        ("f.yaml", "T_imu_lidar: [1, 2\n", "not valid YAML"),
        ("g.toml", "[T_imu_lidar\n", "not valid TOML"),
        ("h.yaml", "T_imu_lidar:\n  translation_m: [0, 0, 0]\n  rpy: [0, 0, 0]\n", "unknown key"),
    ],
)
def test_bad_extrinsic_files(tmp_path, name, text, message):
    path = tmp_path / name
    path.write_text(text)
    with pytest.raises(GnssError, match=message):
        read_extrinsic(path)


def test_missing_extrinsic_file(tmp_path):
    with pytest.raises(GnssError, match="not found"):
        read_extrinsic(tmp_path / "none.toml")
