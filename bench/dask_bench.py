"""A bake on Dask LocalClusters of 1, 2, 4 single-thread workers: time per stage and the bytes each task ships.

    .venv/bin/python -m bench.dask_bench --scene ../wt/notes/prof/sponza8.pkl            # Sponza Final
    .venv/bin/python -m bench.dask_bench --scene S.pkl --workers 1,2 --photons 200000   # smaller

``--scene`` is a pickled ``core.scene.Scene`` (e.g. Sponza joined into one object with the
add-on's UVs). Each worker count gets a fresh LocalCluster; the coordinator traces its own
ray batches on one thread. Per run it prints and writes (``--out``, JSON):

- wall seconds per pipeline stage (``BakeStats``) and in total, the coordinator's CPU seconds;
- per stage closure (``trace_photons``, ``refine_records``, ``interpolate``, ...): calls on the
  cluster, tasks, compute seconds per task (from Dask's task stream), closure bytes per call;
- bytes shipped: large arrays (once per bake, to every worker), closures (once per call, to
  every worker), and the pickled ``(index, chunk)`` per task;
- whether the light maps equal the first run's bit for bit.

bench/README.md ("Dask") turns these into a projection for a 16-machine cluster.
"""
from __future__ import annotations

import argparse
import json
import pickle
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _load():
    sys.path.insert(0, str(ROOT))
    import pdic_bootstrap

    return pdic_bootstrap.load()


def task_seconds(stream: list, calls: list) -> dict:
    """{closure name: [compute seconds of each task]} from Dask's task stream records."""
    name_of = {call.key: call.name for call in calls}
    out = defaultdict(list)
    for record in stream:
        prefix = str(record["key"]).rpartition("-")[0]
        if prefix in name_of:
            out[name_of[prefix]] += [s["stop"] - s["start"] for s in record["startstops"] if s["action"] == "compute"]
    return out


def per_stage(calls: list, seconds: dict) -> dict:
    """Per closure: calls, tasks, mean and max task compute seconds, closure bytes per call, task bytes."""
    rows = defaultdict(lambda: {"calls": 0, "tasks": 0, "closure_bytes": 0, "task_bytes": 0, "wall_seconds": 0.0})
    for call in calls:
        row = rows[call.name]
        row["calls"] += 1
        row["tasks"] += call.tasks
        row["closure_bytes"] += call.closure_bytes
        row["task_bytes"] += call.task_bytes
        row["wall_seconds"] += call.seconds
    for name, row in rows.items():
        times = seconds.get(name, [])
        row["task_seconds_mean"] = float(np.mean(times)) if times else None
        row["task_seconds_max"] = float(np.max(times)) if times else None
        row["task_seconds_sum"] = float(np.sum(times)) if times else 0.0
    return dict(rows)


def array_bytes_by_rows(shapes: list, triangles: int) -> dict:
    """Bytes of the shared arrays grouped by what their rows are: triangles, or a row count
    (texel samples, photons, records: compare with the bake's counters)."""
    out = defaultdict(int)
    for dtype, shape in shapes:
        rows = shape[0] if shape else 1
        out["triangles" if rows == triangles else str(rows)] += int(np.prod(shape)) * np.dtype(dtype).itemsize
    return dict(sorted(out.items(), key=lambda kv: -kv[1]))


def run_once(scene, settings, workers: int) -> tuple[dict, dict]:
    from distributed import get_task_stream

    from pdic.core.dask_executor import DaskExecutor
    from pdic.core.pipeline import bake

    with DaskExecutor(f"local:{workers}", threads=1) as executor:
        cpu, wall = time.process_time(), time.perf_counter()
        with get_task_stream(executor.client) as stream:
            result = bake(scene, settings, executor=executor)
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
        s = executor.shipping
        report = {
            "workers": workers, "wall_seconds": wall, "coordinator_cpu_seconds": cpu,
            "stage_seconds": result.stats.get("seconds", {}),
            "array_bytes": s.array_bytes, "arrays": s.arrays, "closure_bytes": s.scattered_bytes,
            "task_bytes": s.task_bytes, "tasks": s.tasks, "calls_on_cluster": s.calls,
            "calls_on_coordinator": s.local_calls,
            "triangles": len(scene.geometry.positions),
            "per_stage": per_stage(s.per_call, task_seconds(stream.data, s.per_call)),
            "array_bytes_by_rows": array_bytes_by_rows(s.array_shapes, len(scene.geometry.positions)),
            "counters": result.stats.get("counters", {}),
        }
    return report, result.lightmaps


def print_report(r: dict) -> None:
    mb = 1e-6
    print(f"\n== {r['workers']} worker(s): {r['wall_seconds']:.1f} s wall, coordinator {r['coordinator_cpu_seconds']:.1f} "
          f"CPU s; shipped {r['array_bytes'] * mb:.1f} MB of arrays ({r['arrays']}) once, "
          f"{r['closure_bytes'] * mb:.2f} MB of closures, {r['task_bytes'] / max(r['tasks'], 1):.0f} B per task "
          f"({r['tasks']} tasks, {r['calls_on_cluster']} calls on the cluster, {r['calls_on_coordinator']} here)")
    print("  stage seconds: " + ", ".join(f"{k} {v:.1f}" for k, v in r["stage_seconds"].items()))
    for name, row in r["per_stage"].items():
        mean = row["task_seconds_mean"]
        print(f"  {name:<34s} {row['calls']:4d} calls {row['tasks']:6d} tasks  "
              f"{'-' if mean is None else f'{mean:.3f}'} s/task  {row['task_seconds_sum']:.1f} task-s  "
              f"{row['wall_seconds']:.1f} s wall  {row['closure_bytes'] / row['calls'] * mb:.2f} MB closure/call")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", required=True, help="pickled core.scene.Scene")
    p.add_argument("--workers", default="1,2,4", help="comma-separated worker counts (default 1,2,4)")
    p.add_argument("--quality", default="FINAL", choices=("PREVIEW", "FINAL"))
    p.add_argument("--photons", type=int, help="override the preset's photon count")
    p.add_argument("--out", default=str(ROOT / "bench" / "results" / "dask.json"), help="JSON report")
    args = p.parse_args(argv)
    _load()
    from pdic.core.settings import preset

    scene = pickle.loads(Path(args.scene).read_bytes())
    overrides = {"photons": args.photons} if args.photons else {}
    settings = preset(args.quality, threads=1, **overrides)
    reports, first = [], None
    for workers in (int(w) for w in args.workers.split(",")):
        report, maps = run_once(scene, settings, workers)
        first = first if first is not None else maps
        report["lightmaps_equal_first_run"] = all(np.array_equal(first[k], maps[k]) for k in first)
        print_report(report)
        reports.append(report)
        out = Path(args.out)  # after every run: a long series that is stopped keeps what it measured
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps({"scene": args.scene, "quality": args.quality, "photons": settings.photons,
                                   "runs": reports}, indent=1, default=str))
        print(f"written: {out}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
