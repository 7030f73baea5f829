"""Find the bags a batch runs on, and give each one a stable, unique output-folder name.

An input is one of:

* a file: taken as a bag as named (a ROS1 ``.bag``, or a ROS2 ``.db3``/``.mcap`` storage file; a
  ``metadata.yaml`` stands for its folder);
* a ROS2 bag folder (a folder holding ``metadata.yaml``): one bag;
* any other folder: searched recursively for ``*.bag`` files, ROS2 bag folders, lone
  ``.db3``/``.mcap`` files and ``*.pcap`` captures (raw Velodyne packets); folders whose name
  starts with a dot are skipped;
* a glob pattern (``data/2024-*/*.bag``, ``**`` recursive): every match, each treated as above
  except that files that are not bags by name are ignored.

Several ROS1 split files of one drive are separate bags to a batch (``lidar3d run`` can join them).
"""

from __future__ import annotations

import glob
import os
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path

from lidar3d.errors import BagError

__all__ = ["BagInput", "bag_names", "discover_bags"]

_GLOB_CHARS = frozenset("*?[")
_STORAGE_SUFFIXES = (".db3", ".mcap")
_UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")


@dataclass(frozen=True, slots=True)
class BagInput:
    """One bag of a batch.

    Attributes:
        path: absolute path of the ``.bag`` file, ROS2 bag folder, or storage file.
        name: output-folder name, unique within the batch (see :func:`bag_names`).
        kind: ``"ros1"``, ``"ros2"`` (a bag folder), ``"ros2-storage"`` (a lone .db3/.mcap) or ``"pcap"``
            (raw Velodyne packets).
    """

    path: Path
    name: str
    kind: str

    @property
    def stem(self) -> str:
        """The bag's own name without ``.bag``/``.db3``/``.mcap``."""
        return self.path.name if self.kind == "ros2" else self.path.stem


def _kind_of_file(path: Path) -> tuple[Path, str]:
    if path.name == "metadata.yaml":
        return path.parent, "ros2"
    if path.suffix == ".pcap":
        return path, "pcap"
    if path.suffix in _STORAGE_SUFFIXES:
        if (path.parent / "metadata.yaml").is_file():
            return path.parent, "ros2"
        return path, "ros2-storage"
    return path, "ros1"


def _walk(folder: Path) -> Iterable[tuple[Path, str]]:
    """Bags below ``folder``, not descending into ROS2 bag folders."""
    if (folder / "metadata.yaml").is_file():
        yield folder, "ros2"
        return
    for root, dirs, files in os.walk(folder):
        root_path = Path(root)
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        bag_dirs = [d for d in dirs if (root_path / d / "metadata.yaml").is_file()]
        for d in bag_dirs:
            yield root_path / d, "ros2"
        dirs[:] = [d for d in dirs if d not in bag_dirs]
        for name in sorted(files):
            if name.startswith("."):
                continue
            if name.endswith(".bag"):
                yield root_path / name, "ros1"
            elif name.endswith(_STORAGE_SUFFIXES):
                yield root_path / name, "ros2-storage"
            elif name.endswith(".pcap"):
                yield root_path / name, "pcap"


def _expand(item: str | Path) -> list[tuple[Path, str]]:
    text = str(item)
    path = Path(text).expanduser()
    if path.exists():
        if path.is_dir():
            found = sorted(_walk(path))
            if not found:
                raise BagError(
                    f"{text}: no bag in this folder (looked for *.bag, ROS2 bag folders, *.db3, *.mcap, *.pcap)"
                )
            return found
        return [_kind_of_file(path)]
    if _GLOB_CHARS & set(text):
        matches = sorted(glob.glob(os.path.expanduser(text), recursive=True))
        found = []
        for match in matches:
            match_path = Path(match)
            if match_path.is_dir():
                found.extend(sorted(_walk(match_path)))
            elif match_path.name.endswith((".bag", ".pcap", *_STORAGE_SUFFIXES)) or match_path.name == "metadata.yaml":
                found.append(_kind_of_file(match_path))
        if not found:
            raise BagError(f"{text}: no bag matches this pattern")
        return found
    raise BagError(f"{text}: no such file or folder")


def _components(path: Path, kind: str) -> list[str]:
    """Sanitised name parts, innermost first: the bag's stem, then its parent folders."""
    stem = path.name if kind == "ros2" else path.stem
    parts = [stem, *(p.name for p in path.parents if p.name)]
    cleaned = [_UNSAFE.sub("_", p).lstrip(".") or "_" for p in parts]
    return cleaned


def bag_names(paths: Sequence[Path], kinds: Sequence[str]) -> list[str]:
    """Shortest unique names: the stem, then ``parent__stem``, ``grandparent__parent__stem``...

    Only bags whose names collide get longer names, so a bag keeps its name (and its finished
    outputs) when unrelated bags are added to a later run. Characters other than letters, digits,
    ``.``, ``_`` and ``-`` become ``_``.
    """
    parts = [_components(p, k) for p, k in zip(paths, kinds)]
    depth = [1] * len(parts)
    while True:
        names = ["__".join(reversed(p[:d])) for p, d in zip(parts, depth)]
        groups: dict[str, list[int]] = {}
        for index, name in enumerate(names):
            groups.setdefault(name, []).append(index)
        grown = False
        for members in groups.values():
            if len(members) > 1:
                for index in members:
                    if depth[index] < len(parts[index]):
                        depth[index] += 1
                        grown = True
        if not grown:
            break
    seen: dict[str, int] = {}
    unique = []
    for name in names:
        count = seen.get(name, 0) + 1
        seen[name] = count
        unique.append(name if count == 1 else f"{name}-{count}")
    return unique


def discover_bags(inputs: Sequence[str | Path]) -> list[BagInput]:
    """Every bag named by ``inputs`` (files, ROS2 folders, folders, globs), without duplicates.

    Order: inputs in the order given, the bags of each folder or glob sorted by path.

    Raises:
        BagError: an input that does not exist, a folder or pattern without any bag, or no input.
    """
    if not inputs:
        raise BagError("no input given (bags, ROS2 bag folders, folders or glob patterns)")
    found: list[tuple[Path, str]] = []
    seen: set[Path] = set()
    for item in inputs:
        for path, kind in _expand(item):
            resolved = path.resolve()
            if resolved not in seen:
                seen.add(resolved)
                found.append((resolved, kind))
    names = bag_names([p for p, _ in found], [k for _, k in found])
    return [BagInput(path, name, kind) for (path, kind), name in zip(found, names)]
