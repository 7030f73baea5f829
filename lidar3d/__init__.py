"""lidar3d: LiDAR SLAM for Velodyne VLP-16 recordings in the style of LeGO-LOAM."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("lidar3d")
except PackageNotFoundError:  # running from a source tree without installation
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
