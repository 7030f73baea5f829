"""``lidar3d completion bash|zsh``: the generated script completes subcommands, options, option
values and scenarios when bash runs it (issue 22)."""

from __future__ import annotations

import shutil
import subprocess

import pytest

from lidar3d.cli.main import main

pytestmark = pytest.mark.skipif(shutil.which("bash") is None, reason="bash not installed")


@pytest.fixture(scope="module")
def script(tmp_path_factory):
    path = tmp_path_factory.mktemp("completion") / "lidar3d.bash"
    import contextlib
    import io

    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        assert main(["completion", "bash"]) == 0
    path.write_text(buffer.getvalue())
    return path


def _complete(script, line: str, cwd) -> list[str]:
    """What Tab offers at the end of ``line`` (a trailing space: a new empty word)."""
    words = line.split() + ([""] if line.endswith(" ") else [])
    array = " ".join(f"'{w}'" for w in words)
    program = (
        f"source {script}; COMP_WORDS=({array}); COMP_CWORD={len(words) - 1}; _lidar3d; "
        'printf "%s\\n" "${COMPREPLY[@]}"'
    )
    done = subprocess.run(["bash", "-c", program], capture_output=True, text=True, cwd=cwd, timeout=20)
    assert done.returncode == 0, done.stderr
    return [w for w in done.stdout.splitlines() if w]


@pytest.mark.parametrize(
    "line, expected",
    [
        ("lidar3d ru", ["run"]),
        ("lidar3d b", ["batch"]),
        ("lidar3d batch --no-", ["--no-loop"]),
        ("lidar3d batch in --map", ["--map-voxel"]),
        ("lidar3d run --loop-source p", ["place"]),
        ("lidar3d batch x --engine ", ["local", "ray"]),
        ("lidar3d simulate ci", ["city_traffic"]),
        ("lidar3d view --p", ["--png"]),
        ("lidar3d completion ", ["bash", "zsh"]),
    ],
)
def test_tab_offers(script, tmp_path, line, expected):
    assert _complete(script, line, tmp_path) == expected


def test_verbosity_after_the_subcommand_and_files_for_bags(script, tmp_path):
    assert {"-q", "--quiet", "-v", "--verbose"} <= set(_complete(script, "lidar3d info bag -", tmp_path))
    (tmp_path / "drive.bag").write_bytes(b"")
    (tmp_path / "results").mkdir()
    assert _complete(script, "lidar3d run dr", tmp_path) == ["drive.bag"]
    assert _complete(script, "lidar3d run drive.bag --out ", tmp_path) == ["results"]  # folders only


def test_zsh_script_loads_the_bash_one_through_bashcompinit(capsys):
    assert main(["completion", "zsh"]) == 0
    text = capsys.readouterr().out
    assert "bashcompinit" in text and "complete -o filenames -o bashdefault -F _lidar3d lidar3d" in text
