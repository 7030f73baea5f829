"""Batch processing: SLAM over many bags, locally or on Ray, resumable, with one report.

Modules, one concept each:

* :mod:`~lidar3d.batch.discovery`: bags from files, ROS2 bag folders, folders and globs;
* :mod:`~lidar3d.batch.span_match`: a SPAN log (and extrinsic file) per bag, by pattern or time overlap;
* :mod:`~lidar3d.batch.fingerprint`: content and job fingerprints (what makes a bag up to date);
* :mod:`~lidar3d.batch.jobs`: one bag's job, run into a staging folder and published by a rename;
* :mod:`~lidar3d.batch.engines`: the local process pool and Ray;
* :mod:`~lidar3d.batch.progress`: progress across bags;
* :mod:`~lidar3d.batch.report`: summary.csv, summary.json, report.html;
* :mod:`~lidar3d.batch.runner`: :func:`run_batch`, the library twin of ``lidar3d batch``.

Nothing heavy is imported here: worker processes import this package before they limit their
BLAS/OpenMP threads.
"""

from lidar3d.batch.discovery import BagInput, discover_bags
from lidar3d.batch.engines import Engine
from lidar3d.batch.fingerprint import content_fingerprint, job_fingerprint
from lidar3d.batch.jobs import BagJob, JobResult, JobStatus, RunOptions, process_job
from lidar3d.batch.progress import BatchProgress, ProgressDisplay
from lidar3d.batch.report import ROW_FIELDS, ReportPaths
from lidar3d.batch.runner import BatchOutcome, default_workers, run_batch
from lidar3d.batch.span_match import SpanMatch, match_span_logs

__all__ = [
    "ROW_FIELDS",
    "BagInput",
    "BagJob",
    "BatchOutcome",
    "BatchProgress",
    "Engine",
    "JobResult",
    "JobStatus",
    "ProgressDisplay",
    "ReportPaths",
    "RunOptions",
    "SpanMatch",
    "content_fingerprint",
    "default_workers",
    "discover_bags",
    "job_fingerprint",
    "match_span_logs",
    "process_job",
    "run_batch",
]
