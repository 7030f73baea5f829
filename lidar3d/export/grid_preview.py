"""PNG preview of an occupancy grid: the map_server image in metres, with the driven path.

Drawn with Pillow (imported only when a preview is drawn): matplotlib's import and rendering took
0.8-1.2 s of a ``lidar3d grid`` of 100-850 scans, Pillow takes a few hundredths. A grid larger than
:data:`MAX_SIDE_PX` is shrunk by a whole factor, each pixel the darkest of its block (occupied over
unknown over free), so that no obstacle disappears from the preview.
"""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np

from lidar3d.io.atomic import write_bytes_atomic

__all__ = ["MAX_SIDE_PX", "grid_preview_png", "write_grid_preview"]

MAX_SIDE_PX = 1200  # the map's longer side in the preview at most
_MARGIN_PX = (64, 36, 16, 44)  # left, top, right, bottom: tick labels, title, axis names
_PATH_RGB = (255, 127, 14)  # matplotlib's tab:orange
_TEXT_RGB = (0, 0, 0)


def grid_preview_png(
    image: np.ndarray, resolution_m: float, origin_xy_m: np.ndarray, path_xy_m: np.ndarray, *, title: str
) -> bytes:
    """PNG bytes of the map_server ``image`` (rows, cols; row 0 = highest y) placed in world metres
    (ticks on x and y), with the (N,2) driven path in colour and ``title`` above."""
    from PIL import Image, ImageDraw, ImageFont

    rows, cols = image.shape
    factor = max(1, math.ceil(max(rows, cols) / MAX_SIDE_PX))
    pixels = _darkest_per_block(np.asarray(image, np.uint8), factor)
    metres_per_px = resolution_m * factor
    left, top, right, bottom = _MARGIN_PX
    height, width = pixels.shape
    canvas = Image.new("RGB", (left + width + right, top + height + bottom), "white")
    canvas.paste(Image.fromarray(pixels).convert("RGB"), (left, top))
    draw = ImageDraw.Draw(canvas)
    font = ImageFont.load_default(size=12)
    x0, y_top = float(origin_xy_m[0]), float(origin_xy_m[1]) + rows * resolution_m

    def to_canvas(x: float, y: float) -> tuple[float, float]:
        return left + (x - x0) / metres_per_px, top + (y_top - y) / metres_per_px

    if len(path_xy_m):
        draw.line([to_canvas(x, y) for x, y in np.asarray(path_xy_m, float)], fill=_PATH_RGB, width=2)
    draw.rectangle((left - 1, top - 1, left + width, top + height), outline=_TEXT_RGB)
    x_span, y_span = cols * resolution_m, rows * resolution_m
    for x in _ticks(x0, x0 + x_span):
        u, _ = to_canvas(x, y_top)
        draw.line((u, top + height, u, top + height + 4), fill=_TEXT_RGB)
        draw.text((u, top + height + 6), f"{x:g}", fill=_TEXT_RGB, font=font, anchor="mt")
    for y in _ticks(y_top - y_span, y_top):
        _, v = to_canvas(x0, y)
        draw.line((left - 5, v, left - 1, v), fill=_TEXT_RGB)
        draw.text((left - 7, v), f"{y:g}", fill=_TEXT_RGB, font=font, anchor="rm")
    draw.text((left + width / 2, top + height + 24), "x (m)", fill=_TEXT_RGB, font=font, anchor="mt")
    draw.text((4, top + height / 2), "y (m)", fill=_TEXT_RGB, font=font, anchor="lm")
    draw.text((left + width / 2, top / 2), title, fill=_TEXT_RGB, font=font, anchor="mm")
    if len(path_xy_m):
        legend_y = top / 2
        draw.line((left + width - 110, legend_y, left + width - 90, legend_y), fill=_PATH_RGB, width=2)
        draw.text((left + width - 85, legend_y), "driven path", fill=_TEXT_RGB, font=font, anchor="lm")
    buffer = io.BytesIO()
    canvas.save(buffer, format="PNG")
    return buffer.getvalue()


def write_grid_preview(path: str | Path, *args, **kwargs) -> Path:
    """Write :func:`grid_preview_png` to ``path`` atomically; returns the path."""
    write_bytes_atomic(path, grid_preview_png(*args, **kwargs))
    return Path(path)


def _darkest_per_block(image: np.ndarray, factor: int) -> np.ndarray:
    """(ceil(rows / factor), ceil(cols / factor)) the darkest pixel of each ``factor`` square of the
    (rows, cols) uint8 ``image`` (the last blocks cut short by the image's edge)."""
    if factor == 1:
        return image
    rows, cols = image.shape
    padded = np.full((-(-rows // factor) * factor, -(-cols // factor) * factor), 255, np.uint8)
    padded[:rows, :cols] = image
    return padded.reshape(padded.shape[0] // factor, factor, padded.shape[1] // factor, factor).min(axis=(1, 3))


def _ticks(low: float, high: float) -> np.ndarray:
    """Round tick positions (1, 2 or 5 times a power of ten apart, 4 to 10 of them) within [low, high]."""
    span = max(high - low, 1e-9)
    step = 10.0 ** math.floor(math.log10(span / 4))
    for multiple in (1.0, 2.0, 5.0, 10.0):
        if span / (step * multiple) <= 10:
            step *= multiple
            break
    return np.arange(math.ceil(low / step), math.floor(high / step) + 1) * step
