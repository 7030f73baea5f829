"""The Ray engine (a local 2-CPU Ray instance) writes exactly what the local process pool writes."""

from __future__ import annotations

import dataclasses
import json

import pytest
from test_batch_local import OUTPUTS, simulate_bags

from lidar3d.batch import run_batch
from lidar3d.summary import RunSummary, read_summary

ray = pytest.importorskip("ray", reason="Ray is not installed (pip install 'lidar3d[ray]')")

# Fields of summary.json that measure the run rather than the result (any "..._ms..." timing too);
# the manifest too: eval/report.json names the batch folder (the other entries are compared apart).
TIMING_FIELDS = {"runtime_s", "scans_per_s", "evaluation", "outputs"}


def _results_only(summary: RunSummary) -> dict:
    fields = dataclasses.fields(summary)
    return {f.name: getattr(summary, f.name) for f in fields if f.name not in TIMING_FIELDS and "_ms" not in f.name}


def test_ray_and_local_engines_write_identical_outputs(tmp_path):
    data = simulate_bags(tmp_path, names=("a", "b"), with_corrupt=False)
    options = {"span_pattern": "novatel_span.log", "extrinsics": "{parent}/extrinsics.toml", "workers": 2}
    local = run_batch([data], tmp_path / "local", **options)
    remote = run_batch([data], tmp_path / "ray", engine="ray", **options)
    assert not ray.is_initialized()  # the instance run_batch started is shut down again

    assert local.counts["done"] == remote.counts["done"] == 2
    assert [r["name"] for r in local.rows] == [r["name"] for r in remote.rows] == ["a__scans", "b__scans"]
    for name in ("a__scans", "b__scans"):
        for output in OUTPUTS:
            assert (local.out_dir / name / output).read_bytes() == (remote.out_dir / name / output).read_bytes(), output
        summaries = [read_summary(o.out_dir / name / "summary.json") for o in (local, remote)]
        assert summaries[0].scans == 20
        assert summaries[0].evaluation is not None and summaries[1].evaluation is not None
        assert summaries[0].evaluation.ate == summaries[1].evaluation.ate
        assert _results_only(summaries[0]) == _results_only(summaries[1])
        run_files = [[e for e in s.outputs if not e.path.startswith("eval/")] for s in summaries]
        assert run_files[0] == run_files[1] and len(run_files[0]) >= 8
        jobs = [json.loads((o.out_dir / name / "batch_job.json").read_text()) for o in (local, remote)]
        assert jobs[0]["fingerprint"] == jobs[1]["fingerprint"]

    # The Ray run's folders are up to date for the local engine too: same fingerprints.
    again = run_batch([data], tmp_path / "ray", **options)
    assert again.counts["up to date"] == 2
