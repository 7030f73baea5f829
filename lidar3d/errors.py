"""Exception hierarchy.

Every error that the user can cause (bad file, bad config, bad option) is a subclass of
:class:`Lidar3dError`. The CLI turns these into one line on stderr and exit code 1; any other
exception keeps its traceback because it is a bug.
"""

__all__ = [
    "BagError",
    "ConfigError",
    "GeoreferenceError",
    "GnssError",
    "Lidar3dError",
    "OutputError",
    "PacketError",
    "PointCloudError",
    "RegistrationError",
    "SimulationError",
    "SummaryError",
]


class Lidar3dError(Exception):
    """Base of all errors caused by input, configuration or environment."""


class BagError(Lidar3dError):
    """A bag is missing, unreadable, empty, or lacks the expected topic."""


class ConfigError(Lidar3dError):
    """A configuration file or value is invalid."""


class PointCloudError(Lidar3dError):
    """A PointCloud2 message cannot be decoded."""


class PacketError(Lidar3dError):
    """Raw Velodyne packets (a pcap file, a VelodyneScan topic) cannot be read or decoded."""


class GnssError(Lidar3dError):
    """A GNSS/INS log cannot be read or has no usable solution."""


class GeoreferenceError(Lidar3dError):
    """A run has no usable georeference, or a coordinate reference system cannot be used for an export."""


class RegistrationError(Lidar3dError):
    """Scan registration failed (too few correspondences, degenerate geometry)."""


class SimulationError(Lidar3dError):
    """A simulation scenario or its parameters are invalid."""


class OutputError(Lidar3dError):
    """An output cannot be written."""


class SummaryError(Lidar3dError):
    """A run folder's ``summary.json`` is missing, not JSON, or not of the expected layout."""
