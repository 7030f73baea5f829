"""Fingerprints that decide whether a bag's finished outputs can be reused.

A bag's *content fingerprint* is a SHA-256 over, for every file of the bag (one ``.bag`` file, or
every file of a ROS2 bag folder in sorted order, with its path inside the folder):

* the file size;
* the first and the last :data:`EDGE_BYTES` bytes;
* :data:`N_SAMPLES` blocks of :data:`SAMPLE_BYTES` bytes at evenly spaced offsets in between.

Size and modification time are deliberately not used as the identity: copying or touching a bag
keeps its fingerprint, and a bag rewritten with different content almost always changes its size,
its header (ROS1: the index position and chunk count; ROS2: metadata.yaml), its tail (the ROS1
index, the sqlite/mcap footer) or one of the sampled blocks. It is still a sample, not a full
hash: reading a few MiB per bag keeps a re-run over hundreds of multi-GB bags fast. A bag edited
in place at exactly the same size and only between the sampled blocks goes unnoticed; use
``--overwrite`` after such surgery. Small files (up to ``2 * EDGE_BYTES``) are hashed whole.

A *job fingerprint* adds everything else that decides the outputs: the resolved configuration
(as TOML text), the content fingerprints of the matched SPAN log and of the extrinsic file, and
the lidar3d version.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

from lidar3d.errors import BagError

__all__ = [
    "EDGE_BYTES",
    "N_SAMPLES",
    "SAMPLE_BYTES",
    "bag_size_bytes",
    "content_fingerprint",
    "job_fingerprint",
]

EDGE_BYTES = 1 << 20  # 1 MiB at each end
SAMPLE_BYTES = 64 << 10  # 64 KiB per interior sample
N_SAMPLES = 16
_FORMAT = "lidar3d-content-v1"


def _files_of(path: Path) -> list[tuple[str, Path]]:
    if path.is_dir():
        files = sorted(p for p in path.rglob("*") if p.is_file() and not p.name.startswith("."))
        return [(p.relative_to(path).as_posix(), p) for p in files]
    return [("", path)]


def _hash_file(digest: hashlib._Hash, path: Path) -> None:
    size = path.stat().st_size
    digest.update(f"{size}\n".encode())
    with open(path, "rb") as handle:
        if size <= 2 * EDGE_BYTES:
            digest.update(handle.read())
            return
        digest.update(handle.read(EDGE_BYTES))
        interior = size - 2 * EDGE_BYTES
        step = interior / (N_SAMPLES + 1)
        for k in range(1, N_SAMPLES + 1):
            offset = EDGE_BYTES + int(k * step) - SAMPLE_BYTES // 2
            offset = min(max(offset, EDGE_BYTES), size - EDGE_BYTES - SAMPLE_BYTES)
            handle.seek(offset)
            digest.update(handle.read(SAMPLE_BYTES))
        handle.seek(size - EDGE_BYTES)
        digest.update(handle.read(EDGE_BYTES))


def content_fingerprint(path: str | Path) -> str:
    """``"sha256:<hex>"`` of a file or folder's content, sampled as the module docstring says.

    Raises:
        BagError: the path does not exist or cannot be read.
    """
    path = Path(path)
    digest = hashlib.sha256(f"{_FORMAT}\n".encode())
    try:
        if not path.exists():
            raise BagError(f"{path}: no such file or folder")
        for relative, file in _files_of(path):
            digest.update(f"{relative}\n".encode())
            _hash_file(digest, file)
    except OSError as err:
        raise BagError(f"{path}: cannot read: {err.strerror or err}") from err
    return f"sha256:{digest.hexdigest()}"


def job_fingerprint(
    bag_fingerprint: str,
    config_toml: str,
    *,
    span_fingerprint: str | None,
    extrinsics_fingerprint: str | None,
    version: str,
    run_options: dict[str, object] | None = None,
) -> str:
    """``"sha256:<hex>"`` of everything that determines one bag's outputs.

    ``run_options``: the per-bag run options that differ from their defaults (``{"start": 10}``);
    empty or None adds nothing, so a batch with default options keeps its earlier fingerprints.
    """
    identity: dict[str, object] = {
        "bag": bag_fingerprint,
        "config": config_toml,
        "span_log": span_fingerprint,
        "extrinsics": extrinsics_fingerprint,
        "lidar3d": version,
    }
    if run_options:
        identity["run_options"] = run_options
    text = json.dumps(identity, sort_keys=True, separators=(",", ":"))
    return f"sha256:{hashlib.sha256(text.encode()).hexdigest()}"


def bag_size_bytes(path: Path) -> int:
    """Bytes of a file, or of every file below a folder (used for progress estimates)."""
    if path.is_dir():
        return sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
    return os.path.getsize(path)
