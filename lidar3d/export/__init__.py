"""Adapters that turn results into report files: one module per kind of output.

Nothing is imported here, so ``import lidar3d.export.<module>`` pulls in only what that output needs.
File formats themselves (TUM/KITTI trajectories, PCD, bags) live in :mod:`lidar3d.io`; these modules
compose them, with tables and plots, from the records the algorithm packages return. The modules:

* :mod:`lidar3d.export.span_report` - :func:`~lidar3d.export.span_report.write_span_report`, the SPAN
  evaluation report (``report.json``, ``errors.csv``, TUM files, PNG plots) of a
  :class:`~lidar3d.metrics.span_eval.SpanEvaluation`, and the text table ``lidar3d eval`` prints.
* :mod:`lidar3d.export.loop_report` - ``loops.csv``, ``pose_graph.g2o`` and the top view with the loop
  closures.
* :mod:`lidar3d.export.front_end` - :func:`~lidar3d.export.front_end.write_front_end_scan`, one scan's
  ground, clusters, outliers and features as PCD files (``lidar3d features``).
"""
