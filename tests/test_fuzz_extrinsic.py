"""Property-based (fuzz) test of the extrinsic file reader: only the project's own errors come out,
and whatever it accepts is a proper rigid transform.

Valid TOML and YAML files of every form (quaternion, roll/pitch/yaw, 4x4 matrix, matrix with
translation and rotation) are mutated: characters flipped, cut, inserted, deleted (including
non-UTF-8 bytes), and numbers replaced by hostile values (nan, inf, 1e400, strings, lists, tables).
Budget: tests/fuzz_settings.py (``make fuzz`` for the big one).
"""

import tempfile
from pathlib import Path

import numpy as np
import pytest
from fuzz_settings import fuzz_settings
from hypothesis import given
from hypothesis import strategies as st

from lidar3d.errors import Lidar3dError
from lidar3d.gnss import read_extrinsic, write_extrinsic

_ROWS = "[[0.0, -1.0, 0.0, 0.1], [1.0, 0.0, 0.0, 0.3], [0.0, 0.0, 1.0, 0.8], [0.0, 0.0, 0.0, 1.0]]"
_QUATERNION = "[0.0, 0.0, 0.7071067811865476, 0.7071067811865476]"
_FILES = [
    ("toml", f"[T_imu_lidar]\ntranslation_m = [0.1, 0.3, 0.8]\nquaternion_xyzw = {_QUATERNION}\n"),
    (
        "toml",
        "# comment\n[T_imu_lidar]\ntranslation_m = [0.1, 0.3, 0.8]\nrpy_deg = [0, 0, 90]\n"
        "[imu_to_antenna]\ntranslation_m = [0.0, 0.5, 1.2]\n",
    ),
    ("toml", f"[T_imu_lidar]\nmatrix = {_ROWS}\n"),
    ("toml", f"[T_imu_lidar]\nmatrix = {_ROWS}\ntranslation_m = [0.1, 0.3, 0.8]\nquaternion_xyzw = {_QUATERNION}\n"),
    ("yaml", "T_imu_lidar:\n  translation_m: [0.1, 0.3, 0.8]\n  rpy_deg: [0.0, 0.0, 90.0]\n"),
    ("yaml", f"T_imu_lidar:\n  translation_m: [0.1, 0.3, 0.8]\n  quaternion_xyzw: {_QUATERNION}\n"),
    (
        "yaml",
        "T_imu_lidar:\n  matrix:\n    - [0.0, -1.0, 0.0, 0.1]\n    - [1.0, 0.0, 0.0, 0.3]\n"
        "    - [0.0, 0.0, 1.0, 0.8]\n    - [0.0, 0.0, 0.0, 1.0]\n  rpy_deg: [0, 0, 90]\n",
    ),
]
_TOKENS = [
    "nan",
    ".nan",
    "inf",
    "-inf",
    ".inf",
    "1e400",
    "-1e400",
    "1e-400",
    '"1.0"',
    "'x'",
    "true",
    "null",
    "~",
    "[]",
    "[1, 2]",
    "[[1]]",
    "{}",
    "{a = 1}",
    "{a: 1}",
    "1979-05-27",
    "0x10",
    "1_000",
    "9" * 400,
    "-0.0",
    "*a",
    "&a 1",
    "!!python/object:os.system",
    "\xe9",
    "]",
    "[",
    ",",
    ":",
    "=",
    "\n",
    "\t",
    "#",
]


@st.composite
def extrinsic_files(draw) -> tuple[str, bytes]:
    suffix, text = draw(st.sampled_from(_FILES))
    data = bytearray(text.encode())
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["flip", "cut", "insert", "delete", "number", "number"]))
        at = draw(st.integers(0, max(len(data) - 1, 0)))
        if op == "flip" and data:
            data[at] = draw(st.integers(0, 255))
        elif op == "cut":
            data = data[:at]
        elif op == "insert":
            data[at:at] = draw(st.binary(min_size=1, max_size=8))
        elif op == "delete":
            del data[at : at + draw(st.integers(1, 12))]
        else:
            pieces = bytearray(data).replace(b"[", b"[ ").replace(b",", b" ,").split(b" ")
            numeric = [k for k, piece in enumerate(pieces) if piece[:1].isdigit() or piece[:1] == b"-"]
            if numeric:
                k = draw(st.sampled_from(numeric))
                pieces[k] = draw(st.sampled_from(_TOKENS)).encode("latin-1")
                data = bytearray(b" ".join(pieces))
    return suffix, bytes(data)


_FOLDER = tempfile.TemporaryDirectory(prefix="lidar3d-fuzz-extrinsic-")


@pytest.mark.filterwarnings("ignore::ruamel.yaml.error.ReusedAnchorWarning")  # a mutation's "&a 1, &a 1"
@fuzz_settings(300)
@given(extrinsic_files())
def test_fuzz_extrinsic_reader_raises_only_project_errors(case):
    suffix, data = case
    path = Path(_FOLDER.name) / f"extrinsic.{suffix}"
    path.write_bytes(data)
    try:
        T = read_extrinsic(path)
    except Lidar3dError as err:
        assert "\n" not in str(err) and str(err).startswith(str(path))
    else:
        assert T.shape == (4, 4) and np.all(np.isfinite(T))
        assert np.array_equal(T[3], [0.0, 0.0, 0.0, 1.0])
        R = T[:3, :3]
        assert np.allclose(R.T @ R, np.eye(3), atol=1e-5) and abs(np.linalg.det(R) - 1.0) < 1e-5
        written = path.with_name("written.toml")
        write_extrinsic(written, T)  # what it accepts, it can write back
        assert np.allclose(read_extrinsic(written), T, atol=1e-9)
