"""Occupancy grids as ROS ``map_server`` maps: a YAML file beside a binary PGM image.

The conventions of ``map_server`` / ``nav2_map_server`` (``map_saver`` writes the same):

* the image's top row is the grid's highest y (north), its left column the lowest x;
* ``origin: [x, y, yaw]`` is the world pose of the image's *lower-left* pixel corner;
* with ``negate: 0`` a pixel value v means occupancy p = (255 - v) / 255; in ``mode: trinary`` a pixel
  with p > ``occupied_thresh`` is occupied, p < ``free_thresh`` free, anything else unknown;
* ``map_saver``'s values: occupied 0, free 254, unknown 205 (p = 0.196, not below ``free_thresh``).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lidar3d.errors import OutputError
from lidar3d.io.atomic import write_bytes_atomic, write_text_atomic

__all__ = [
    "FREE_THRESH",
    "FREE_VALUE",
    "OCCUPIED_THRESH",
    "OCCUPIED_VALUE",
    "UNKNOWN_VALUE",
    "MapServerMap",
    "read_map_server",
    "trinary_image",
    "write_map_server",
]

OCCUPIED_THRESH = 0.65
FREE_THRESH = 0.196
OCCUPIED_VALUE = 0
FREE_VALUE = 254
UNKNOWN_VALUE = 205


@dataclass(frozen=True, slots=True)
class MapServerMap:
    """A map as map_server reads it.

    Attributes:
        image: (rows, cols) uint8 pixels, row 0 at the top (highest y).
        resolution_m: metres per pixel.
        origin: (x, y, yaw) of the lower-left pixel corner, world frame.
        image_name: the image file named in the YAML.
    """

    image: np.ndarray
    resolution_m: float
    origin: tuple[float, float, float]
    image_name: str


def trinary_image(probability: np.ndarray) -> np.ndarray:
    """The PGM pixels of a (nx, ny) occupancy-probability grid (index [i, j]: x then y, NaN or 0.5
    where unknown): occupied 0, free 254, unknown 205, row 0 = highest y."""
    image = np.full(probability.shape, UNKNOWN_VALUE, np.uint8)
    image[probability > OCCUPIED_THRESH] = OCCUPIED_VALUE
    image[probability < FREE_THRESH] = FREE_VALUE
    return np.ascontiguousarray(image.T[::-1])


def write_map_server(yaml_path: str | Path, image: np.ndarray, resolution_m: float, origin_xy_m: np.ndarray) -> Path:
    """Write ``yaml_path`` and the PGM beside it (same stem, ``.pgm``); returns the PGM path.

    Args:
        image: (rows, cols) uint8 from :func:`trinary_image`.
        resolution_m: metres per pixel.
        origin_xy_m: (2,) world x, y of the lower-left pixel corner.
    """
    yaml_path = Path(yaml_path)
    pgm_path = yaml_path.with_suffix(".pgm")
    rows, cols = image.shape
    header = f"P5\n# lidar3d occupancy grid, {resolution_m:g} m per pixel\n{cols} {rows}\n255\n".encode("ascii")
    write_bytes_atomic(pgm_path, header + np.ascontiguousarray(image, dtype=np.uint8).tobytes())
    x, y = (float(v) for v in origin_xy_m)
    write_text_atomic(
        yaml_path,
        f"image: {pgm_path.name}\n"
        "mode: trinary\n"
        f"resolution: {resolution_m:g}\n"
        f"origin: [{x:.6f}, {y:.6f}, 0.0]\n"
        "negate: 0\n"
        f"occupied_thresh: {OCCUPIED_THRESH}\n"
        f"free_thresh: {FREE_THRESH}\n",
    )
    return pgm_path


def read_map_server(yaml_path: str | Path) -> MapServerMap:
    """Read a map written by :func:`write_map_server` (or ``map_saver``: the keys above, a binary PGM).

    Raises:
        OutputError: a file is missing or not in that form (one line naming it).
    """
    yaml_path = Path(yaml_path)
    try:
        lines = yaml_path.read_text(encoding="utf-8").splitlines()
    except OSError as err:
        raise OutputError(f"{yaml_path}: cannot read the map ({err.strerror or err})") from err
    fields = {}
    for line in lines:
        key, sep, value = line.partition(":")
        if sep and not line.lstrip().startswith("#"):
            fields[key.strip()] = value.strip()
    try:
        origin = tuple(float(v) for v in fields["origin"].strip("[]").split(","))
        resolution = float(fields["resolution"])
        image_name = fields["image"]
    except (KeyError, ValueError) as err:
        raise OutputError(f"{yaml_path}: not a map_server map ({err})") from None
    if len(origin) != 3:
        raise OutputError(f"{yaml_path}: origin must be [x, y, yaw]")
    image = _read_pgm(yaml_path.parent / image_name)
    return MapServerMap(image, resolution, (origin[0], origin[1], origin[2]), image_name)


def _read_pgm(path: Path) -> np.ndarray:
    try:
        data = path.read_bytes()
    except OSError as err:
        raise OutputError(f"{path}: cannot read the map image ({err.strerror or err})") from err
    tokens: list[bytes] = []
    position = 0
    while len(tokens) < 4:
        while position < len(data) and data[position : position + 1].isspace():
            position += 1
        if data[position : position + 1] == b"#":
            position = data.index(b"\n", position) + 1
            continue
        end = position
        while end < len(data) and not data[end : end + 1].isspace():
            end += 1
        tokens.append(data[position:end])
        position = end
    if tokens[0] != b"P5" or tokens[3] != b"255":
        raise OutputError(f"{path}: not a binary 8-bit PGM")
    cols, rows = int(tokens[1]), int(tokens[2])
    pixels = np.frombuffer(data, np.uint8, count=rows * cols, offset=position + 1)
    return pixels.reshape(rows, cols)
