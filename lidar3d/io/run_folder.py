"""A run folder as one consistent set: publication by staging and renames, completion after a kill, checks.

A run folder holds the outputs of one run (trajectories, ``health.csv``, ``map.pcd``, ``dynamic.pcd``, loop outputs,
``config.toml``, ``eval/``) and ``summary.json``, whose manifest (:attr:`lidar3d.summary.RunSummary.outputs`) names
every other file of the set with its size, SHA-256 and rows. :func:`publish_set` replaces the whole
set in three steps:

1. every new or changed file is written into the staging folder ``.publication/`` inside the run
   folder; files of the current set that stay unchanged are only named (``keep``);
2. the new ``summary.json``, with the manifest of the whole new set, is written last into staging:
   the commit point;
3. the staged files are moved onto their names, the files of the previous set that the new one does
   not hold are removed, ``summary.json`` is moved last, and the staging folder is removed.

A kill before step 2 leaves the previous set as it was (the uncommitted staging folder is discarded
by the next publication or reader); a kill inside step 3 leaves a committed publication that
:func:`complete_publication` finishes (every reader calls it first, as SQLite readers roll back a
hot journal). The folder therefore always holds either the previous set or the new one, never a mix;
:func:`check_run_folder` tells which state a folder is in.

Standard library only: the batch runner checks folders before its workers limit their BLAS threads.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import os
import shutil
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from enum import Enum
from pathlib import Path

from lidar3d.errors import OutputError, SummaryError
from lidar3d.io.atomic import write_text_atomic
from lidar3d.summary import OutputFile, RunSummary, read_summary

__all__ = [
    "EVAL_FOLDER",
    "RUN_OUTPUT_NAMES",
    "STAGING_NAME",
    "SUMMARY_NAME",
    "RunFolderCheck",
    "RunFolderState",
    "check_run_folder",
    "check_run_output",
    "complete_publication",
    "describe_file",
    "existing_run_outputs",
    "publish_set",
    "read_run_folder",
]

SUMMARY_NAME = "summary.json"
STAGING_NAME = ".publication"
EVAL_FOLDER = "eval"
# Every name that lidar3d run (and a batch around it) writes at the top of a run folder. A
# publication removes those its new set does not hold, so a rerun never mixes two runs.
RUN_OUTPUT_NAMES = (
    "config.toml",
    "trajectory_tum.txt",
    "trajectory_kitti.txt",
    "trajectory_kitti.times.txt",
    "odometry_tum.txt",
    "keyframes_tum.txt",
    "health.csv",
    "map.pcd",
    "georef.json",
    "trajectory_lidar_only_tum.txt",
    "dynamic.pcd",
    "loops.csv",
    "pose_graph.g2o",
    "trajectory_loops.png",
    "batch_job.json",
    SUMMARY_NAME,
)
_HASH_CHUNK = 1 << 20


class RunFolderState(str, Enum):
    """What a run folder holds."""

    EMPTY = "no outputs"  # no summary and no run output (a run killed before its first publication)
    CONSISTENT = "consistent"  # summary.json and exactly the files its manifest describes
    PENDING = "publication pending"  # a committed publication was interrupted: complete_publication
    INCONSISTENT = "inconsistent"  # anything else (see the problems)


@dataclass(frozen=True, slots=True)
class RunFolderCheck:
    """The verdict of :func:`check_run_folder` on one folder.

    Attributes:
        folder: the run folder.
        state: what it holds.
        summary: its ``summary.json`` (None when absent or unreadable).
        problems: why it is not consistent, one line each (empty when consistent or empty).
        unnamed: run outputs in the folder that the summary does not name (relative paths).
    """

    folder: Path
    state: RunFolderState
    summary: RunSummary | None
    problems: tuple[str, ...] = ()
    unnamed: tuple[str, ...] = ()


def describe_file(folder: Path, path: str, rows: int | None = None) -> OutputFile:
    """The manifest entry of ``folder / path``: size, SHA-256 and ``rows``."""
    digest = hashlib.sha256()
    with open(folder / path, "rb") as handle:
        while chunk := handle.read(_HASH_CHUNK):
            digest.update(chunk)
    return OutputFile(path=path, size_bytes=(folder / path).stat().st_size, sha256=digest.hexdigest(), rows=rows)


def _files_under(folder: Path) -> list[str]:
    """Relative ``/``-separated paths of every file under ``folder``, sorted."""
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file())


def existing_run_outputs(folder: str | Path) -> list[str]:
    """Run outputs present in ``folder`` (names of :data:`RUN_OUTPUT_NAMES`, ``eval/``, the staging
    folder), sorted; empty when the folder does not exist."""
    folder = Path(folder)
    names = [*RUN_OUTPUT_NAMES, EVAL_FOLDER, STAGING_NAME]
    return sorted(name for name in names if (folder / name).exists())


def _current_summary(folder: Path) -> RunSummary | None:
    try:
        return read_summary(folder / SUMMARY_NAME)
    except SummaryError:
        return None


def _remove_empty_folders(folder: Path, relative: str) -> None:
    parent = (folder / relative).parent
    while parent != folder:
        try:
            parent.rmdir()
        except OSError:
            return
        parent = parent.parent


def complete_publication(folder: str | Path) -> bool:
    """Finish an interrupted publication in ``folder``: a committed one is swapped in, an
    uncommitted staging folder removed. Idempotent (a kill inside it is finished by the next call).

    Returns:
        True when there was a staging folder.
    """
    folder = Path(folder)
    staging = folder / STAGING_NAME
    if not staging.is_dir():
        return False
    try:
        new = read_summary(staging / SUMMARY_NAME)
    except SummaryError:  # not committed: the previous set is intact
        shutil.rmtree(staging)
        return True
    old = _current_summary(folder)
    for path in _files_under(staging):
        if path != SUMMARY_NAME:
            (folder / path).parent.mkdir(parents=True, exist_ok=True)
            os.replace(staging / path, folder / path)
    held = {entry.path for entry in new.outputs} | {SUMMARY_NAME}
    previous = {entry.path for entry in old.outputs} if old is not None else set()
    previous |= {name for name in RUN_OUTPUT_NAMES if (folder / name).is_file()}
    if (folder / EVAL_FOLDER).is_dir():
        previous |= {f"{EVAL_FOLDER}/{path}" for path in _files_under(folder / EVAL_FOLDER)}
    for path in sorted(previous - held):
        with contextlib.suppress(FileNotFoundError):
            (folder / path).unlink()
        _remove_empty_folders(folder, path)
    os.replace(staging / SUMMARY_NAME, folder / SUMMARY_NAME)
    shutil.rmtree(staging)
    return True


def publish_set(
    folder: str | Path,
    summary: RunSummary,
    write_files: Callable[[Path], object] | None = None,
    *,
    rows: Mapping[str, int] | None = None,
    keep: Iterable[str] = (),
) -> RunSummary:
    """Replace the set in ``folder`` by a new one, by staging and renames (see the module docstring).

    Args:
        summary: the new summary; its ``outputs`` are replaced by the manifest of the new set.
        write_files: called with the staging folder; writes every new or changed file into it
            (under the names they get in ``folder``).
        rows: what the written files hold, counted (relative path -> rows), for the manifest.
        keep: files of the current set that stay unchanged (their manifest entries are carried over).

    Returns:
        The summary as published, with its manifest.

    Raises:
        OutputError: the folder cannot be written, or a file to keep is not in the current set.
    """
    folder = Path(folder)
    staging = folder / STAGING_NAME
    try:
        complete_publication(folder)
        staging.mkdir(parents=True)
    except OSError as err:
        raise OutputError(f"{folder}: cannot write the run folder: {err.strerror or err}") from err
    if write_files is not None:
        write_files(staging)
    rows = rows or {}
    entries = {path: describe_file(staging, path, rows.get(path)) for path in _files_under(staging)}
    keep = list(keep)
    if keep:
        current = _current_summary(folder)
        for path in keep:
            entry = current.output(path) if current is not None else None
            if entry is None:
                raise OutputError(f"{folder}: cannot keep {path}: it is not in the published set")
            entries.setdefault(path, entry)
    published = dataclasses.replace(summary, outputs=tuple(entries[path] for path in sorted(entries)))
    write_text_atomic(staging / SUMMARY_NAME, published.to_json())  # the commit point
    complete_publication(folder)
    return published


def _expected_rows(summary: RunSummary) -> dict[str, int]:
    """Rows each file must hold by the summary's own counts."""
    expected = dict.fromkeys(
        ("trajectory_tum.txt", "trajectory_kitti.txt", "trajectory_kitti.times.txt", "odometry_tum.txt", "health.csv"),
        summary.scans,
    )
    expected.update({"keyframes_tum.txt": summary.keyframes, "map.pcd": summary.map_points})
    expected["loops.csv"] = summary.loop_candidates
    if summary.dynamic_points is not None:
        expected["dynamic.pcd"] = summary.dynamic_points
    return expected


def _file_problems(folder: Path, entry: OutputFile, verify_content: bool) -> list[str]:
    path = folder / entry.path
    if not path.is_file():
        return [f"{entry.path}: missing"]
    size = path.stat().st_size
    if size != entry.size_bytes:
        return [f"{entry.path}: {size} bytes, the summary says {entry.size_bytes}"]
    if verify_content and describe_file(folder, entry.path).sha256 != entry.sha256:
        return [f"{entry.path}: content differs from the summary's SHA-256"]
    return []


def check_run_folder(folder: str | Path, *, verify_content: bool = True, extra: Iterable[str] = ()) -> RunFolderCheck:
    """Whether ``folder`` holds exactly the set its ``summary.json`` describes (nothing is changed).

    Args:
        verify_content: compare every file's SHA-256 too (else sizes only: cheap on big maps).
        extra: top-level names that may sit beside the set without being named (a batch's
            ``batch_job.json``).
    """
    folder = Path(folder)
    if (folder / STAGING_NAME / SUMMARY_NAME).is_file():
        return RunFolderCheck(folder, RunFolderState.PENDING, None, ("a publication was interrupted",))
    outputs = [name for name in existing_run_outputs(folder) if name not in (STAGING_NAME, *extra)]
    if not (folder / SUMMARY_NAME).exists():
        if not outputs:
            return RunFolderCheck(folder, RunFolderState.EMPTY, None)
        return RunFolderCheck(folder, RunFolderState.INCONSISTENT, None, ("outputs without summary.json",))
    try:
        summary = read_summary(folder / SUMMARY_NAME)
    except SummaryError as err:
        return RunFolderCheck(folder, RunFolderState.INCONSISTENT, None, (str(err),))
    problems = [] if summary.outputs else ["summary.json has no manifest of the outputs"]
    expected = _expected_rows(summary)
    for entry in summary.outputs:
        problems += _file_problems(folder, entry, verify_content)
        if entry.path in expected and entry.rows != expected[entry.path]:
            problems.append(f"{entry.path}: {entry.rows} rows, the summary's counts say {expected[entry.path]}")
    named = {entry.path for entry in summary.outputs} | {SUMMARY_NAME, *extra}
    present = [name for name in outputs if name != EVAL_FOLDER]
    if (folder / EVAL_FOLDER).is_dir():
        present += [f"{EVAL_FOLDER}/{path}" for path in _files_under(folder / EVAL_FOLDER)]
    unnamed = tuple(sorted(path for path in present if path not in named))
    state = RunFolderState.INCONSISTENT if problems else RunFolderState.CONSISTENT
    return RunFolderCheck(folder, state, summary, tuple(problems), unnamed)


def read_run_folder(folder: str | Path, *, verify_content: bool = False, extra: Iterable[str] = ()) -> RunSummary:
    """The summary of the consistent set in ``folder``, after finishing an interrupted publication.

    Raises:
        OutputError: the folder holds no outputs, or not the set its summary describes (one line).
    """
    folder = Path(folder)
    try:
        complete_publication(folder)
    except OSError as err:
        raise OutputError(f"{folder}: cannot finish an interrupted publication: {err.strerror or err}") from err
    check = check_run_folder(folder, verify_content=verify_content, extra=extra)
    if check.state is RunFolderState.EMPTY:
        raise OutputError(f"{folder}: no run outputs")
    if check.state is not RunFolderState.CONSISTENT:
        raise OutputError(f"{folder}: not a consistent run folder: {'; '.join(check.problems)}")
    assert check.summary is not None  # a consistent folder has a parsed summary
    return check.summary


def check_run_output(path: str | Path) -> None:
    """Check a file read out of a run folder (``lidar3d eval out/trajectory_tum.txt``) against the
    folder's summary: when the summary names it, its size and SHA-256 must match. A file in no run
    folder, or one the summary does not name, passes. An interrupted publication is finished first.

    Raises:
        OutputError: the file is not the one the summary describes (one line).
    """
    path = Path(path)
    folder = path.parent
    with contextlib.suppress(OSError):
        complete_publication(folder)
    if (folder / STAGING_NAME / SUMMARY_NAME).is_file():
        raise OutputError(f"{path}: an interrupted publication in {folder} could not be finished")
    summary = _current_summary(folder)
    names = [path.name, path.with_suffix(".times.txt").name] if path.suffix == ".txt" else [path.name]
    for name in names:
        entry = summary.output(name) if summary is not None else None
        problems = _file_problems(folder, entry, verify_content=True) if entry is not None else []
        if problems:
            raise OutputError(f"{path}: not the file its run folder's summary.json describes ({problems[0]})")
