"""Benchmark the synthetic grasp generator (grasps/s and samples/s).

Usage::

    python benchmarks/bench_synthetic.py            # ~1,000 samples, full size (250 x 350)
    python benchmarks/bench_synthetic.py --full     # ~7,800 samples, the real dataset's size
    python benchmarks/bench_synthetic.py --objects 20 --size 60x80 --workers 1

A *sample* is one ``grasp=g/augmentation=k`` directory (both fingers), as in the real
dataset's "7,840 sets of raw data". The tree is written under ``--tmp`` (default /tmp)
and deleted afterwards unless ``--keep``. Prints one JSON line with the machine, the
parameters, wall time, grasps/s, samples/s and the size on disk.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

from tactile_compliance.synthetic import generate_burgess_tree

# The default mix gives ~19 sample directories per object (5-8 grasps x ~3.2
# augmentations: 7,318 from 390 objects when measured on 2026-11-26), so these object
# counts give ~1,000 and at least the real dataset's 7,800 samples.
OBJECTS_FOR_1000_SAMPLES = 50
OBJECTS_FOR_7800_SAMPLES = 420


def _cpu_model() -> str:
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, check=False).stdout
        for line in out.splitlines():
            if line.startswith("Model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def _disk_bytes(root: Path) -> int:
    return sum(p.stat().st_size for p in root.rglob("*") if p.is_file())


def main(argv: list[str] | None = None) -> None:
    """Run the benchmark and print a JSON summary."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--full", action="store_true", help="~7,800 samples (real dataset size)")
    parser.add_argument("--objects", type=int, default=None, help="number of objects")
    parser.add_argument("--size", default="250x350", help="image size HxW")
    parser.add_argument("--workers", type=int, default=None, help="processes (default: CPUs)")
    parser.add_argument("--dtype", default="float16", choices=["float16", "float32", "float64"])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--tmp", default=tempfile.gettempdir(), help="where to write the tree")
    parser.add_argument("--keep", action="store_true", help="keep the generated tree")
    args = parser.parse_args(argv)
    height, width = (int(v) for v in args.size.lower().split("x"))
    default_objects = OBJECTS_FOR_7800_SAMPLES if args.full else OBJECTS_FOR_1000_SAMPLES
    n_objects = args.objects or default_objects
    out = Path(tempfile.mkdtemp(prefix="bench-synthetic-", dir=args.tmp))
    cpu_start = os.times()
    start = time.perf_counter()
    try:
        report = generate_burgess_tree(
            out / "tree",
            n_objects=n_objects,
            seed=args.seed,
            image_size=(height, width),
            progress=False,
            workers=args.workers,
            dtype=args.dtype,
        )
        wall = time.perf_counter() - start
        cpu = os.times()
        cpu_s = (cpu.user - cpu_start.user) + (cpu.children_user - cpu_start.children_user)
        cpu_s += (cpu.system - cpu_start.system) + (cpu.children_system - cpu_start.children_system)
        summary = {
            "machine": {
                "nproc": os.cpu_count(),
                "cpu": _cpu_model(),
                "load_average_1min_at_end": round(os.getloadavg()[0], 2),
            },
            "objects": n_objects,
            "image_size": [height, width],
            "dtype": args.dtype,
            "workers": report.workers,
            "grasps": report.grasps,
            "samples": report.samples,
            "wall_s": round(wall, 1),
            "cpu_s": round(cpu_s, 1),
            "grasps_per_s": round(report.grasps / wall, 2),
            "samples_per_s": round(report.samples / wall, 2),
            "cpu_ms_per_grasp": round(1e3 * cpu_s / max(report.grasps, 1), 1),
            "disk_gb": round(_disk_bytes(out) / 1e9, 2),
        }
        print(json.dumps(summary))
    finally:
        if args.keep:
            print(f"kept {out}")
        else:
            shutil.rmtree(out, ignore_errors=True)


if __name__ == "__main__":
    main()
