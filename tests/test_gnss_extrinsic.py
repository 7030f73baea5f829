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


# --- 4x4 matrix (issue 21, defect 9) -------------------------------------------------------------

_MATRIX_TOML = "matrix = [[0.0, -1.0, 0.0, 0.1], [1.0, 0.0, 0.0, 0.3], [0.0, 0.0, 1.0, 0.8], [0, 0, 0, 1]]\n"
_MATRIX_YAML = (
    "  matrix:\n    - [0.0, -1.0, 0.0, 0.1]\n    - [1.0, 0.0, 0.0, 0.3]\n    - [0.0, 0.0, 1.0, 0.8]\n"
    "    - [0.0, 0.0, 0.0, 1.0]\n"
)


@pytest.mark.parametrize(
    "name,text",
    [
        ("m.toml", "[T_imu_lidar]\n" + _MATRIX_TOML),
        ("mt.toml", "[T_imu_lidar]\n" + _MATRIX_TOML + "translation_m = [0.1, 0.3, 0.8]\n"),
        (
            "mq.toml",
            "[T_imu_lidar]\n" + _MATRIX_TOML + "translation_m = [0.1, 0.3, 0.8]\n"
            "quaternion_xyzw = [0.0, 0.0, 0.7071067811865476, 0.7071067811865476]\n",
        ),
        ("mr.toml", "[T_imu_lidar]\n" + _MATRIX_TOML + "rpy_deg = [0, 0, 90]\n"),
        ("m.yaml", "T_imu_lidar:\n" + _MATRIX_YAML),
        (
            "mflow.yml",
            "T_imu_lidar:\n  matrix: [[0, -1, 0, 0.1], [1, 0, 0, 0.3], [0, 0, 1, 0.8], [0, 0, 0, 1]]\n"
            "  rpy_deg: [0.0, 0.0, 90.0]\n",
        ),
    ],
)
def test_matrix_is_accepted_alone_or_agreeing(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    assert np.allclose(read_extrinsic(path), EXPECTED, atol=1e-12)


def test_matrix_within_tolerance_is_accepted_and_last_row_made_exact(tmp_path):
    T = EXPECTED.copy()
    T[3] = [0.0, 0.0, 4e-7, 1.0 + 5e-7]
    T[0, 1] += 4e-7
    rows = ", ".join("[" + ", ".join(repr(float(v)) for v in row) + "]" for row in T)
    path = tmp_path / "x.toml"
    path.write_text(f"[T_imu_lidar]\nmatrix = [{rows}]\n")
    result = read_extrinsic(path)
    assert np.array_equal(result[3], [0.0, 0.0, 0.0, 1.0]) and result[0, 1] == T[0, 1]


@pytest.mark.parametrize(
    "text,message",
    [
        ("matrix = [[1, 0, 0], [0, 1, 0], [0, 0, 1]]\n", r"T_imu_lidar.matrix must be a 4x4 matrix \(4 rows of 4"),
        ("matrix = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0]]\n", "must be a 4x4 matrix"),
        ("matrix = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, nan]]\n", r"must be a 4x4 matrix .*\(finite\)"),
        (
            "matrix = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 1e-5, 1]]\n",
            r"matrix last row must be 0 0 0 1, got \[0.0, 0.0, 1e-05, 1.0\]",
        ),
        (
            "matrix = [[1, 0, 0, 0], [0, 1.001, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]\n",
            r"matrix rotation is not orthonormal \(\|R\^T R - I\| = 2.00e-03 > 1e-06\)",
        ),
        (
            "matrix = [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, -1, 0], [0, 0, 0, 1]]\n",
            r"matrix rotation has determinant -1.000000, not \+1 \(a reflection\)",
        ),
        (
            _MATRIX_TOML + "translation_m = [0.1, 0.3, 0.81]\n",
            r"T_imu_lidar.matrix and T_imu_lidar.translation_m disagree by 0.01 m \(tolerance 1e-06 m\)",
        ),
        (
            _MATRIX_TOML + "rpy_deg = [0, 0, 89.9]\n",
            r"T_imu_lidar.matrix and T_imu_lidar.rpy_deg disagree by 0.1 deg \(tolerance 1e-06 rad\)",
        ),
        (
            _MATRIX_TOML + "quaternion_xyzw = [0, 0, 0, 1]\n",
            r"T_imu_lidar.matrix and T_imu_lidar.quaternion_xyzw disagree by 90 deg",
        ),
        (
            _MATRIX_TOML + "rpy_deg = [0, 0, 90]\nquaternion_xyzw = [0, 0, 0, 1]\n",
            "exactly one of quaternion_xyzw .* beside matrix, or neither",
        ),
        ("quaternion_xyzw = [0, 0, 0, 1]\n", r"needs translation_m \(3 numbers\) or matrix \(4x4\)"),
    ],
)
def test_bad_matrix_files(tmp_path, text, message):
    path = tmp_path / "bad.toml"
    path.write_text("[T_imu_lidar]\n" + text)
    with pytest.raises(GnssError, match=message) as info:
        read_extrinsic(path)
    assert "\n" not in str(info.value) and str(info.value).startswith(f"{path}: ")


def test_bad_matrix_in_yaml_names_the_file(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("T_imu_lidar:\n  matrix: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]]\n")
    with pytest.raises(GnssError, match=f"^{path}: T_imu_lidar.matrix must be a 4x4 matrix"):
        read_extrinsic(path)


def test_non_utf8_extrinsic_file_is_one_line(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_bytes(b"[T_imu_lidar]\ntranslation_m = [0, 0, 0\xff]\n")
    with pytest.raises(GnssError, match=r"extrinsic file is not UTF-8 text \(byte 38\)"):
        read_extrinsic(path)
