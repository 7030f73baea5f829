"""Match a NovAtel SPAN log (and an extrinsic file) to each bag of a batch.

Two ways, one per batch:

* **pattern** (``--span-pattern``): a path template with the placeholders ``{stem}`` (bag name
  without ``.bag``; a ROS2 bag folder's name), ``{name}`` (the bag's batch output name),
  ``{parent}`` (the folder holding the bag) and ``{folder}`` (that folder's name). A relative
  result is taken relative to the bag's folder, so ``novatel_span.log`` means "the log beside the
  bag" and ``/logs/{stem}.gps`` a log of the same name elsewhere. Glob characters are allowed;
  when several files match, the one overlapping the bag longest in time wins.
* **time overlap** (``--span-dir``): every file below the folder that reads as a SPAN log is a
  candidate; a bag gets the log whose solutions (INSPVA/INSPVAX, else BESTPOS) overlap the bag's
  log-time span longest. GPS time becomes bag time with ``gnss.leap_seconds`` and
  ``gnss.time_offset_s`` of the configuration. Time spans are cached in the batch output folder
  (``.batch/time_ranges.json``), keyed by content fingerprint, so a re-run reads no log or bag
  again.

The extrinsic file (``--extrinsics``) is one file for every bag, or a pattern with the same
placeholders when it contains ``{``.
"""

from __future__ import annotations

import glob
import json
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from lidar3d.batch.discovery import BagInput
from lidar3d.batch.fingerprint import content_fingerprint
from lidar3d.errors import ConfigError, GnssError, Lidar3dError

__all__ = [
    "SpanMatch",
    "TimeRangeCache",
    "bag_time_range",
    "expand_pattern",
    "log_time_range",
    "match_span_logs",
    "resolve_extrinsics",
]

log = logging.getLogger(__name__)

TimeRange = tuple[int, int]

# Files below --span-dir that are certainly not SPAN logs (outputs, bags, configs, images).
_NOT_LOGS = frozenset(
    {".bag", ".db3", ".mcap", ".yaml", ".yml", ".toml", ".json", ".png", ".jpg", ".pcd", ".csv", ".html", ".py", ".md"}
)
_BAG_MAGICS = (b"#ROSBAG", b"SQLite format 3\x00", b"\x89MCAP")


@dataclass(frozen=True, slots=True)
class SpanMatch:
    """The SPAN log chosen for one bag (``None``: no log) and how it was chosen, in words."""

    span_log: Path | None
    how: str


class TimeRangeCache:
    """Time spans of logs and bags, keyed by content fingerprint, persisted as JSON.

    ``path=None`` keeps the cache in memory only.
    """

    def __init__(self, path: Path | None = None) -> None:
        self.path = path
        self._data: dict[str, list[int] | None] = {}
        self._dirty = False
        if path is not None and path.is_file():
            try:
                loaded = json.loads(path.read_text(encoding="utf-8"))
                if isinstance(loaded, dict):
                    self._data = {str(k): v for k, v in loaded.items()}
            except (OSError, ValueError):
                log.warning("%s: unreadable time-range cache; rebuilding it", path)

    def get(self, key: str, compute: Callable[[], TimeRange | None]) -> TimeRange | None:
        if key not in self._data:
            value = compute()
            self._data[key] = list(value) if value is not None else None
            self._dirty = True
        stored = self._data[key]
        return (int(stored[0]), int(stored[1])) if stored else None

    def save(self) -> None:
        if self.path is None or not self._dirty:
            return
        from lidar3d.io.atomic import write_text_atomic

        write_text_atomic(self.path, json.dumps(self._data, indent=1, sort_keys=True) + "\n")
        self._dirty = False


def log_time_range(path: str | Path, gnss_config=None) -> TimeRange | None:
    """First and last solution time of a SPAN log in bag-clock UNIX ns; None when it has none.

    Raises:
        GnssError: the file cannot be read.
    """
    from lidar3d.config import GnssConfig
    from lidar3d.gnss import gps_to_unix_ns, read_span_log

    config = gnss_config or GnssConfig()
    span_log = read_span_log(path)
    messages = span_log.ins or span_log.positions
    if not messages:
        return None
    stamps = gps_to_unix_ns(
        [m.gps_week for m in messages], [m.gps_seconds for m in messages], config.leap_seconds, config.time_offset_s
    )
    return int(stamps.min()), int(stamps.max())


def bag_time_range(path: str | Path) -> TimeRange | None:
    """Log time of a bag's first and last message (UNIX ns), or of a pcap's first and last data
    packet (host clock); None when it cannot be read."""
    from lidar3d.io.packet_source import PacketScanSource, is_packet_input
    from lidar3d.io.scan_source import ScanSource

    try:
        if is_packet_input([path], None):
            from lidar3d.config import Config

            with PacketScanSource(path, Config(), quiet=True) as packets:
                packets.count_sweeps()  # a pass over the packets: the last one's time
                start_ns, end_ns = packets.start_end_ns
            return None if start_ns is None or end_ns is None else (int(start_ns), int(end_ns))
        with ScanSource(path) as source:
            if source.start_ns is None or source.end_ns is None:
                return None
            return int(source.start_ns), int(source.end_ns)
    except Lidar3dError as err:
        log.info("%s: no time span for SPAN log matching: %s", path, err)
        return None


def _placeholders(bag: BagInput) -> dict[str, str]:
    return {"stem": bag.stem, "name": bag.name, "parent": str(bag.path.parent), "folder": bag.path.parent.name}


def expand_pattern(pattern: str, bag: BagInput) -> str:
    """The pattern with the bag's placeholders filled in, made absolute against the bag's folder.

    Raises:
        ConfigError: an unknown placeholder or a malformed pattern.
    """
    try:
        text = pattern.format_map(_placeholders(bag))
    except KeyError as err:
        raise ConfigError(
            f"pattern {pattern!r}: unknown placeholder {{{err.args[0]}}} "
            "(known: {stem}, {name}, {parent}, {folder})"
        ) from None
    except (ValueError, IndexError) as err:
        raise ConfigError(f"pattern {pattern!r}: {err}") from None
    path = Path(text).expanduser()
    return str(path if path.is_absolute() else bag.path.parent / path)


def _overlap_ns(a: TimeRange, b: TimeRange) -> int:
    return min(a[1], b[1]) - max(a[0], b[0])


def _best_by_overlap(
    bag_range: TimeRange | None, candidates: Sequence[tuple[Path, TimeRange | None]]
) -> tuple[Path, int] | None:
    if bag_range is None:
        return None
    best: tuple[Path, int] | None = None
    for path, span in candidates:
        if span is None:
            continue
        overlap = _overlap_ns(bag_range, span)
        if overlap > 0 and (best is None or overlap > best[1]):
            best = (path, overlap)
    return best


def _describe_overlap(overlap_ns: int, bag_range: TimeRange) -> str:
    bag_ns = max(bag_range[1] - bag_range[0], 1)
    return f"time overlap {overlap_ns * 1e-9:.1f} s ({100.0 * min(overlap_ns / bag_ns, 1.0):.0f}% of the bag)"


def _looks_like_bag(path: Path) -> bool:
    try:
        with open(path, "rb") as handle:
            head = handle.read(16)
    except OSError:
        return True
    return head.startswith(_BAG_MAGICS)


def _log_candidates(span_dir: Path) -> list[Path]:
    if not span_dir.is_dir():
        raise ConfigError(f"--span-dir {span_dir}: no such folder")
    found = []
    for path in sorted(span_dir.rglob("*")):
        if any(part.startswith(".") for part in path.relative_to(span_dir).parts):
            continue
        if not path.is_file() or path.suffix.lower() in _NOT_LOGS or _looks_like_bag(path):
            continue
        found.append(path)
    return found


class _Ranges:
    """Time ranges of bags and logs through the cache; content fingerprints computed once."""

    def __init__(self, cache: TimeRangeCache, gnss_config, fingerprints: dict[Path, str]) -> None:
        self.cache = cache
        self.gnss = gnss_config
        self.fingerprints = fingerprints

    def _fingerprint(self, path: Path) -> str:
        if path not in self.fingerprints:
            self.fingerprints[path] = content_fingerprint(path)
        return self.fingerprints[path]

    def bag(self, path: Path) -> TimeRange | None:
        return self.cache.get(f"bag {self._fingerprint(path)}", lambda: bag_time_range(path))

    def log(self, path: Path) -> TimeRange | None:
        key = f"log {self._fingerprint(path)} leap={self.gnss.leap_seconds} offset={self.gnss.time_offset_s!r}"

        def compute() -> TimeRange | None:
            try:
                return log_time_range(path, self.gnss)
            except GnssError as err:
                log.info("%s: not used as a SPAN log: %s", path, err)
                return None

        return self.cache.get(key, compute)


def match_span_logs(
    bags: Sequence[BagInput],
    *,
    span_dir: str | Path | None = None,
    span_pattern: str | None = None,
    gnss_config=None,
    cache: TimeRangeCache | None = None,
    fingerprints: dict[Path, str] | None = None,
) -> dict[str, SpanMatch]:
    """The SPAN log of every bag, keyed by bag name (see the module docstring for the rules).

    ``fingerprints`` (path -> content fingerprint) is reused and filled in, so the caller hashes
    no file twice.

    Raises:
        ConfigError: both or a missing ``span_dir``, or a malformed pattern.
    """
    from lidar3d.config import GnssConfig

    if span_dir is not None and span_pattern is not None:
        raise ConfigError("give --span-dir or --span-pattern, not both")
    if span_dir is None and span_pattern is None:
        return {bag.name: SpanMatch(None, "no SPAN log requested") for bag in bags}
    ranges = _Ranges(
        cache or TimeRangeCache(None), gnss_config or GnssConfig(), fingerprints if fingerprints is not None else {}
    )
    matches: dict[str, SpanMatch] = {}
    if span_pattern is not None:
        for bag in bags:
            expanded = expand_pattern(span_pattern, bag)
            files = (
                sorted(Path(p) for p in glob.glob(expanded) if Path(p).is_file())
                if glob.has_magic(expanded)
                else ([Path(expanded)] if Path(expanded).is_file() else [])
            )
            if not files:
                matches[bag.name] = SpanMatch(None, f"no file {expanded}")
            elif len(files) == 1:
                matches[bag.name] = SpanMatch(files[0].resolve(), "pattern")
            else:
                bag_range = ranges.bag(bag.path)
                best = _best_by_overlap(bag_range, [(f, ranges.log(f)) for f in files])
                if best is None:
                    matches[bag.name] = SpanMatch(
                        None, f"{len(files)} files match {expanded}, none overlaps the bag in time"
                    )
                else:
                    assert bag_range is not None
                    matches[bag.name] = SpanMatch(
                        best[0].resolve(), f"pattern, {_describe_overlap(best[1], bag_range)}"
                    )
    else:
        assert span_dir is not None  # neither given returned above
        candidates = _log_candidates(Path(span_dir))
        logs = [(path.resolve(), ranges.log(path)) for path in candidates]
        usable = [(p, r) for p, r in logs if r is not None]
        if not usable:
            log.warning("%s: no SPAN log found (no file with INSPVA/INSPVAX or BESTPOS solutions)", span_dir)
        for bag in bags:
            bag_range = ranges.bag(bag.path)
            best = _best_by_overlap(bag_range, usable)
            if best is not None:
                assert bag_range is not None
                matches[bag.name] = SpanMatch(best[0], _describe_overlap(best[1], bag_range))
            elif bag_range is None:
                matches[bag.name] = SpanMatch(None, "bag unreadable, no time span to match")
            else:
                matches[bag.name] = SpanMatch(None, f"no log in {span_dir} overlaps the bag in time")
    if cache is not None:
        cache.save()
    return matches


def resolve_extrinsics(extrinsics: str | Path | None, bags: Sequence[BagInput]) -> dict[str, Path | None]:
    """The extrinsic file of every bag: one file for all, or a placeholder pattern per bag.

    Raises:
        ConfigError: a single file that does not exist, or a malformed pattern.
    """
    if extrinsics is None:
        return {bag.name: None for bag in bags}
    text = str(extrinsics)
    if "{" in text:
        return {bag.name: Path(expand_pattern(text, bag)) for bag in bags}
    path = Path(text).expanduser()
    if not path.is_file():
        raise ConfigError(f"--extrinsics {text}: no such file")
    resolved = path.resolve()
    return {bag.name: resolved for bag in bags}
