"""Wall time of an experiment grid (default `table1 --quick`) with 1 and 2 Dask workers.

    python benchmarks/bench_grid.py [--store PATH] [--workers 1,2] [--preset table1]
                                    [--objects 48] [--json out.json]

Without --store, a small synthetic store is generated first (the kind the quick presets are
sized for: --objects objects at 72 x 96 px, imported with both fingers) and deleted
afterwards. Every measurement starts from an empty output directory and an empty feature
cache, so each worker count pays for the same work: worker start-up (importing torch and
Lightning), the frozen-backbone feature caches, and every cell of the grid. The speed-up is
relative to the smallest worker count. The load average is printed next to each time because
a busy machine (other jobs on the same cores) slows multi-worker runs most.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import tempfile
import time
from pathlib import Path
from typing import Any

from tactile_compliance.training.cluster import available_cpus
from tactile_compliance.training.experiment import run_experiment


def _make_store(work: Path, objects: int) -> tuple[Path, float]:
    from tactile_compliance.data.burgess import import_burgess
    from tactile_compliance.synthetic.generate import generate_burgess_tree

    start = time.perf_counter()
    generate_burgess_tree(
        work / "raw", n_objects=objects, image_size=(72, 96), seed=0, progress=False
    )
    import_burgess(work / "raw", work / "store", progress=False, source_name="synthetic")
    shutil.rmtree(work / "raw")
    return work / "store", time.perf_counter() - start


def _measure(preset: str, quick: bool, store: Path, workers: int, out: Path) -> dict[str, Any]:
    shutil.rmtree(store / "features", ignore_errors=True)  # same work for every worker count
    load_before = os.getloadavg()[0]
    start = time.perf_counter()
    summary = run_experiment(
        preset,
        quick=quick,
        store=store,
        workers=workers,
        output_dir=out,
        results=out / "results",  # not the shared runs/results: every count runs every cell
        keep_checkpoints="none",  # a VGG16 checkpoint per cell would fill the disk
        progress=False,
    )
    seconds = time.perf_counter() - start
    table = summary.table()
    cell_times = table["wall_time_s"].dropna() if "wall_time_s" in table else []
    return {
        "workers": workers,
        "wall_s": round(seconds, 1),
        "cells": summary.cells,
        "completed": summary.completed,
        "failed": summary.failed,
        "cell_mean_s": round(float(sum(cell_times) / max(1, len(cell_times))), 2),
        "cell_sum_s": round(float(sum(cell_times)), 1),
        "cell_mean_s_by_model": {
            str(k): round(float(v), 2)
            for k, v in table.groupby("model")["wall_time_s"].mean().items()
        },
        "load_before": round(load_before, 2),
        "load_after": round(os.getloadavg()[0], 2),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--store", type=Path, default=None)
    parser.add_argument("--preset", default="table1")
    parser.add_argument("--full", action="store_true", help="the full preset, not --quick")
    parser.add_argument("--workers", default="1,2")
    parser.add_argument("--objects", type=int, default=32)
    parser.add_argument("--workdir", default=tempfile.gettempdir())
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    work = Path(tempfile.mkdtemp(prefix="bench_grid_", dir=args.workdir))
    try:
        info: dict[str, Any] = {
            "preset": args.preset + ("" if args.full else " --quick"),
            "machine": f"{platform.machine()}, {available_cpus()} CPUs, {platform.system()}",
            "python": platform.python_version(),
        }
        store = args.store
        if store is None:
            store, seconds = _make_store(work, args.objects)
            info["store"] = f"synthetic, {args.objects} objects, 72x96 (made in {seconds:.0f} s)"
        else:
            info["store"] = str(store)
        from tactile_compliance.data.store import GraspStore

        info["samples"] = len(GraspStore.open(store))
        runs = []
        for workers in (int(w) for w in args.workers.split(",")):
            result = _measure(args.preset, not args.full, store, workers, work / f"w{workers}")
            runs.append(result)
            print(json.dumps(result), flush=True)
        reference = min(runs, key=lambda r: r["workers"])  # speed-up relative to the fewest
        for run in runs:
            run["speedup"] = round(reference["wall_s"] / run["wall_s"], 2)
        info["runs"] = runs
        print(f"{info['preset']} on {info['store']} ({info['samples']} samples), {info['machine']}")
        print(
            f"{'workers':>7} {'wall s':>8} {'cells':>6} {'failed':>6} {'cell s':>7} "
            f"{'speed-up':>8} {'load':>10}"
        )
        for run in runs:
            print(
                f"{run['workers']:>7} {run['wall_s']:>8.1f} {run['completed']:>6} "
                f"{run['failed']:>6} {run['cell_mean_s']:>7.2f} {run['speedup']:>8.2f} "
                f"{run['load_before']:>4.1f}-{run['load_after']:<4.1f}"
            )
        if args.json:
            args.json.write_text(json.dumps(info, indent=2) + "\n")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
