"""One option vocabulary across the subcommands (issue 22): the shared options exist under the same
names, parse to the same values, fail with the same message, ``-q``/``-v`` work after the
subcommand, and every option's help states its default."""

from __future__ import annotations

import argparse

import pytest

from lidar3d.batch import RunOptions
from lidar3d.batch.fingerprint import job_fingerprint
from lidar3d.cli.main import build_parser, main
from lidar3d.cli.options import MAP_VOXEL_DEFAULT_M
from lidar3d.config import Config

#: The shared options each command must have (where they apply).
SHARED = {
    "run": ("--topic", "--config", "--out", "--overwrite", "--start", "--max-scans", "--no-loop", "--loop-source",
            "--map-voxel", "--keep-dynamic", "--gnss-factors", "--gnss-hold-out", "--sensor"),
    "batch": ("--topic", "--config", "--out", "--overwrite", "--start", "--max-scans", "--no-loop", "--loop-source",
              "--map-voxel", "--keep-dynamic", "--gnss-factors", "--gnss-hold-out", "--sensor"),
    "features": ("--topic", "--config", "--out", "--start", "--max-scans", "--sensor"),
    "info": ("--topic", "--config", "--sensor"),
    "eval": ("--config", "--out"),
    "simulate": ("--out", "--overwrite"),
}  # fmt: skip

POSITIONAL = {
    "run": ["a.bag"],
    "batch": ["a.bag"],
    "features": ["a.bag"],
    "info": ["a.bag"],
    "eval": ["t.txt", "--span", "s.log"],
    "simulate": [],
}


def _subparsers() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def _options(parser: argparse.ArgumentParser) -> dict[str, argparse.Action]:
    return {flag: action for action in parser._actions for flag in action.option_strings}


@pytest.mark.parametrize("command", SHARED)
def test_shared_options_exist_with_the_same_help(command):
    reference = _options(_subparsers()["run"])
    options = _options(_subparsers()[command])
    for flag in SHARED[command]:
        assert flag in options, f"lidar3d {command} has no {flag}"
        if flag in reference and flag not in ("--out", "--overwrite", "--config"):
            assert options[flag].help == reference[flag].help, f"{command} {flag}"
            assert options[flag].default == reference[flag].default, f"{command} {flag}"


@pytest.mark.parametrize("command", sorted(_subparsers()))
def test_every_option_help_states_its_default(command):
    parser = _subparsers()[command]
    formatter = parser._get_formatter()
    for action in parser._actions:
        if not action.option_strings or action.nargs == 0 or isinstance(action, argparse._HelpAction):
            continue  # positionals, flags (off unless given) and --help
        text = formatter._expand_help(action)
        assert "default" in text or "required" in text, f"lidar3d {command} {action.option_strings[0]}: {text!r}"


@pytest.mark.parametrize("command", SHARED)
@pytest.mark.parametrize("flag, dest", [("-q", "quiet"), ("--verbose", "verbose")])
def test_verbosity_accepted_after_the_subcommand(command, flag, dest):
    out = ["--out", "o"] if "--out" in SHARED[command] else []
    after = build_parser().parse_args([command, *POSITIONAL[command], *out, flag])
    before = build_parser().parse_args([flag, command, *POSITIONAL[command], *out])
    neither = build_parser().parse_args([command, *POSITIONAL[command], *out])
    assert getattr(after, dest) is True and getattr(before, dest) is True and getattr(neither, dest) is False


@pytest.mark.parametrize("command", ["run", "batch", "features"])
def test_scan_selection_parses_and_fails_the_same(command, capsys):
    args = build_parser().parse_args([command, "a.bag", "--out", "o", "--start", "7", "--max-scans", "3"])
    assert (args.start, args.max_scans) == (7, 3)
    assert main([command, "missing.bag", "--out", "o", "--max-scans", "0"]) == 1
    assert capsys.readouterr().err.strip() == f"lidar3d {command}: error: --max-scans must be 1 or more, got 0"
    assert main([command, "missing.bag", "--out", "o", "--start", "-2"]) == 1
    assert capsys.readouterr().err.strip() == f"lidar3d {command}: error: --start must be 0 or more, got -2"


@pytest.mark.parametrize("command", ["run", "batch"])
def test_map_voxel_fails_the_same(command, capsys):
    assert main([command, "missing.bag", "--out", "o", "--map-voxel", "0"]) == 1
    assert (
        capsys.readouterr()
        .err.strip()
        .startswith(f"lidar3d {command}: error: --map-voxel: config mapping.map_voxel_m: 0.0 is out of range")
    )


def test_loop_off_and_loop_source_exclude_each_other(capsys):
    with pytest.raises(SystemExit) as exit_info:
        build_parser().parse_args(["batch", "a", "--out", "o", "--no-loop", "--loop-source", "place"])
    assert exit_info.value.code == 2 and "not allowed with argument" in capsys.readouterr().err


def test_info_quiet_after_the_subcommand_is_not_a_usage_error(tmp_path, capsys):
    assert main(["info", str(tmp_path / "none.bag"), "-q"]) == 1  # a missing bag (1), not a usage error (2)
    assert "lidar3d info: error:" in capsys.readouterr().err


def test_map_voxel_default_in_help_matches_the_config():
    assert Config().mapping.map_voxel_m == MAP_VOXEL_DEFAULT_M


def test_batch_passes_every_per_bag_option(monkeypatch):
    """``batch`` turns the per-bag options of ``run`` into the configuration and run options of every bag."""
    import lidar3d.batch

    seen = {}

    def fake_run_batch(inputs, out, config, **kwargs):
        seen.update(config=config, **kwargs)
        raise KeyboardInterrupt

    monkeypatch.setattr(lidar3d.batch, "run_batch", fake_run_batch)
    argv = ["-q", "batch", "a.bag", "--out", "o", "--topic", "/points", "--start", "4", "--max-scans", "9"]
    argv += ["--no-loop", "--map-voxel", "0.5", "--keep-dynamic", "--sensor", "vlp32c", "--overwrite"]
    assert main(argv) == 130
    config = seen["config"]
    assert config.input.topic == "/points" and config.loop.enabled is False
    assert config.mapping.map_voxel_m == 0.5 and config.dynamic.enabled is False
    assert config.input.packet_model == "vlp32c"
    assert seen["run_options"] == RunOptions(start=4, max_scans=9, gnss_factors=False)
    assert seen["force"] is True


def test_gnss_factors_need_a_span_source(capsys):
    assert main(["batch", "a.bag", "--out", "o", "--gnss-factors"]) == 1
    assert "--gnss-factors needs --span-dir or --span-pattern" in capsys.readouterr().err


def test_default_run_options_keep_earlier_fingerprints():
    """A batch without the new per-bag options finds the bags of an earlier batch up to date."""
    plain = job_fingerprint("b", "c", span_fingerprint=None, extrinsics_fingerprint=None, version="v")
    same = job_fingerprint("b", "c", span_fingerprint=None, extrinsics_fingerprint=None, version="v", run_options={})
    other = job_fingerprint(
        "b", "c", span_fingerprint=None, extrinsics_fingerprint=None, version="v", run_options={"max_scans": 9}
    )
    assert plain == same != other


def test_simulate_names_the_overwrite_flag(tmp_path, capsys):
    out = tmp_path / "sim"
    assert main(["-q", "simulate", "loop", "--out", str(out), "--duration", "0.3"]) == 0
    capsys.readouterr()
    assert main(["simulate", "loop", "--out", str(out), "--duration", "0.3"]) == 1
    assert "pass --overwrite to replace them" in capsys.readouterr().err


# -- Ray: a refused token is named in one line, Ray's own output kept off the terminal ------------


def _fake_ray(monkeypatch, message: str):
    """A stand-in ``ray`` whose ``init`` logs as Ray's C++ core does (to file descriptor 2) and fails."""
    import os
    import sys
    import types

    ray = types.ModuleType("ray")
    exceptions = types.ModuleType("ray.exceptions")

    class RayError(Exception):
        pass

    exceptions.RayError = RayError
    ray.exceptions = exceptions
    ray.is_initialized = lambda: False

    def init(**kwargs):
        os.write(2, (message + "\n").encode())
        raise ConnectionError("Failed to connect to Ray cluster at 192.0.2.2:6391")

    ray.init = init
    monkeypatch.setitem(sys.modules, "ray", ray)
    monkeypatch.setitem(sys.modules, "ray.exceptions", exceptions)


AUTH_LINE = (
    "[2026-12-02 04:45:18,233 W 27721 27721] gcs_client.cc:210: Failed to get cluster ID from GCS server: "
    "Unauthenticated: RPC error: InvalidAuthToken: Authentication token is missing or incorrect"
)


@pytest.mark.parametrize("mode", [None, "token"])
def test_ray_token_refusal_is_one_line_naming_what_to_set(mode, tmp_path, monkeypatch, capfd):
    from lidar3d.batch.engines import run_ray
    from lidar3d.errors import ConfigError

    _fake_ray(monkeypatch, AUTH_LINE)
    if mode is None:
        monkeypatch.delenv("RAY_AUTH_MODE", raising=False)
    else:
        monkeypatch.setenv("RAY_AUTH_MODE", mode)
    log = tmp_path / ".batch" / "ray.log"
    with pytest.raises(ConfigError) as error:
        run_ray([], None, workers=1, address="127.0.0.1:6391", log_path=log)
    text = str(error.value)
    assert "\n" not in text and text.startswith("cannot reach Ray at 127.0.0.1:6391: ")
    if mode is None:
        assert "set RAY_AUTH_MODE=token" in text and "RAY_AUTH_TOKEN" in text
    else:
        assert "refused this client's token" in text
    assert f"Ray's log: {log}" in text
    assert "InvalidAuthToken" in log.read_text()  # kept, but not on the terminal:
    captured = capfd.readouterr()
    assert "InvalidAuthToken" not in captured.err + captured.out


def test_ray_other_connection_failure_keeps_its_reason(tmp_path, monkeypatch):
    from lidar3d.batch.engines import run_ray
    from lidar3d.errors import ConfigError

    _fake_ray(monkeypatch, "some other Ray message")
    with pytest.raises(ConfigError, match=r"cannot start or reach Ray at h:1: Failed to connect to Ray cluster"):
        run_ray([], None, workers=1, address="h:1", log_path=tmp_path / "ray.log")
