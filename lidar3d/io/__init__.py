"""Adapters that touch files: scans in from bags, bags, trajectories and point clouds out.

Nothing is imported here, so ``import lidar3d.io.<module>`` stays cheap. The modules:

* :mod:`lidar3d.io.scan_source` - :func:`~lidar3d.io.scan_source.open_scan_source`, the scan source of
  any input, and :class:`~lidar3d.io.scan_source.ScanSource`, a lazy, time-ordered scan source over
  PointCloud2 in ROS1 bags (split files merged) and ROS2 bag folders (sqlite3, mcap);
  :mod:`lidar3d.io.scan_reading` - what every scan source shares (read totals, the lidar topic).
* raw Velodyne packets: :mod:`lidar3d.io.packet_source` (:class:`~lidar3d.io.packet_source.PacketScanSource`),
  :mod:`lidar3d.io.packet_inputs` (pcap and VelodyneScan packet streams), :mod:`lidar3d.io.pcap_reader`,
  :mod:`lidar3d.io.velodyne_packets` (layout, factory bytes, model detection, sweep cut, NMEA),
  :mod:`lidar3d.io.packet_decoder` (velodyne-decoder), :mod:`lidar3d.io.packet_info` (the twin of
  ``lidar3d info`` on packets), :mod:`lidar3d.io.convert` (the twin of ``lidar3d convert``).
* :mod:`lidar3d.io.bag_inputs` - one opened input per storage (ROS1 ``.bag``, ROS2 folder or file)
  that lists topics and yields raw messages; :mod:`lidar3d.io.scan_decoder` - serialised message to
  :class:`~lidar3d.records.Scan`, the one decoding (ring renumbering included) every command uses.
* :mod:`lidar3d.io.bag_writer` - :func:`~lidar3d.io.bag_writer.write_scan_bag`, scans to a bag.
* :mod:`lidar3d.io.bag_info` - :func:`~lidar3d.io.bag_info.bag_info`, the twin of ``lidar3d info``.
* :mod:`lidar3d.io.pointcloud2` - PointCloud2 <-> :class:`~lidar3d.records.Scan` (field variants).
* :mod:`lidar3d.io.ros1_recovery`, :mod:`~lidar3d.io.db3_recovery`, :mod:`~lidar3d.io.mcap_recovery` -
  salvage of truncated inputs: ROS1 bags without an index, ``.db3`` files cut short, ``.mcap``
  files without a footer (killed recordings).
* :mod:`lidar3d.io.trajectory_io` - TUM and KITTI trajectories; :mod:`lidar3d.io.pcd` - PCD files;
  :mod:`lidar3d.io.atomic` - write-then-rename helpers.
"""
