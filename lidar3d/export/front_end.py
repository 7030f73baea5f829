"""Adapter: what the front end saw in one scan, as a folder of PCD files (``lidar3d features``).

:func:`write_front_end_scan` writes the files of :data:`FRONT_END_FILES`, all in the lidar frame:
ground points, the lifted points (the slope tests took them for ground, the surface check did not:
bases of objects far out), the points of kept clusters (``label`` field: cluster id), outliers
(points of rejected clusters), and the four feature clouds (``ring`` field). The folder is built beside its
final place and renamed, so it is either complete or absent.

Only the standard library is imported at the top: the CLI reads :data:`FRONT_END_FILES` to build its
help, which must stay instant; NumPy and the PCD writer are imported when a scan is written.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

from lidar3d.errors import OutputError

if TYPE_CHECKING:
    from lidar3d.features.frontend import FrontEndResult

__all__ = ["FRONT_END_FILES", "write_front_end_scan"]

FRONT_END_FILES = (
    "ground.pcd",
    "lifted.pcd",
    "clusters.pcd",
    "outliers.pcd",
    "edge_sharp.pcd",
    "edge_less_sharp.pcd",
    "planar_flat.pcd",
    "planar_less_flat.pcd",
)


def write_front_end_scan(folder: Path, result: FrontEndResult) -> None:
    """Write the eight clouds of one scan's front-end ``result`` into ``folder`` (replaced if present).

    Raises :class:`~lidar3d.errors.OutputError` when the folder cannot be created or written.
    """
    import numpy as np

    from lidar3d.io.pcd import write_pcd

    segmentation, features = result.segmentation, result.features
    image = segmentation.image
    points = segmentation.scan.points
    ground_cells = image.point_index[segmentation.ground_mask]
    lifted_cells = image.point_index[segmentation.lifted_mask]
    cluster_cells = segmentation.cluster_label >= 0
    outlier_cells = image.point_index[segmentation.outlier_mask]
    try:
        staging = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", suffix=".partial", dir=folder.parent))
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(staging, 0o777 & ~umask)  # mkdtemp makes it private; the result is an ordinary folder
    except OSError as err:
        raise OutputError(f"{folder}: cannot create a folder beside it: {err.strerror}") from err
    try:
        write_pcd(staging / "ground.pcd", points[ground_cells])
        write_pcd(staging / "lifted.pcd", points[lifted_cells])
        write_pcd(
            staging / "clusters.pcd",
            points[image.point_index[cluster_cells]],
            label=segmentation.cluster_label[cluster_cells].astype(np.int32),
        )
        write_pcd(staging / "outliers.pcd", points[outlier_cells])
        for name, cloud in (
            ("edge_sharp.pcd", features.sharp),
            ("edge_less_sharp.pcd", features.less_sharp),
            ("planar_flat.pcd", features.flat),
            ("planar_less_flat.pcd", features.less_flat),
        ):
            write_pcd(staging / name, cloud.points, ring=cloud.ring.astype(np.int32))
        if folder.exists():
            shutil.rmtree(folder)
        os.replace(staging, folder)
    except OSError as err:
        raise OutputError(f"{folder}: cannot write: {err}") from err
    finally:
        if staging.exists():
            shutil.rmtree(staging, ignore_errors=True)
