"""Import throughput (samples/s) and peak memory of `import burgess` on a full-size tree.

    python benchmarks/bench_import.py [--samples 2000] [--size 250x350] [--workdir /tmp]

Writes a tree in the exact dataset layout (float32 pickles, random difference images),
imports it in a child process and reports samples/s and the child's peak RSS next to
the tree's size: a streaming importer keeps peak memory far below the data size.
The tree and store are deleted afterwards.
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from burgess_tree import write_tree

CHILD = """
import json, resource, sys, time
from tactile_compliance.data.burgess import import_burgess
start = time.perf_counter()
report = import_burgess(sys.argv[1], sys.argv[2], progress=False)
seconds = time.perf_counter() - start
peak_kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(json.dumps({"samples": report.samples_imported, "seconds": seconds, "peak_kib": peak_kib}))
"""


def _tree_bytes(root: Path) -> int:
    return sum(p.stat().st_size for p in root.rglob("*") if p.is_file())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=2000)
    parser.add_argument("--size", default="250x350")
    parser.add_argument("--workdir", default=tempfile.gettempdir())
    args = parser.parse_args()
    height, width = (int(v) for v in args.size.split("x"))
    # 2 fingers per augmentation directory; 10 objects x 5 grasps x 5 augmentations = 500 dirs.
    directories = max(1, args.samples // 2)
    n_objects = max(1, directories // 25)
    objects = {f"obj_{i:03d}": (10.0 ** (4 + i % 7), "Rubber", "Sphere") for i in range(n_objects)}
    work = Path(tempfile.mkdtemp(prefix="bench_import_", dir=args.workdir))
    try:
        start = time.perf_counter()
        write_tree(
            work / "src",
            objects,
            grasps=5,
            augmentations=5,
            size=(height, width),
            dtype=np.float32,
            keep=False,
        )
        write_seconds = time.perf_counter() - start
        tree_gb = _tree_bytes(work / "src") / 1e9
        result = subprocess.run(
            [sys.executable, "-c", CHILD, str(work / "src"), str(work / "store")],
            check=True,
            capture_output=True,
            text=True,
        )
        measured = json.loads(result.stdout.strip().splitlines()[-1])
        store_gb = _tree_bytes(work / "store") / 1e9
    finally:
        shutil.rmtree(work, ignore_errors=True)
    peak_gb = measured["peak_kib"] / 1e6
    print(
        f"machine        : {platform.processor() or platform.machine()}, "
        f"{resource.getpagesize()} B pages, python {platform.python_version()}"
    )
    print(
        f"tree           : {measured['samples']} samples at {height}x{width}, "
        f"{tree_gb:.2f} GB of float32 pickles (written in {write_seconds:.0f} s)"
    )
    print(
        f"import         : {measured['seconds']:.1f} s, "
        f"{measured['samples'] / measured['seconds']:.1f} samples/s"
    )
    print(f"store          : {store_gb:.2f} GB (uint8 frames)")
    print(f"peak memory    : {peak_gb:.2f} GB RSS ({100 * peak_gb / tree_gb:.1f} % of the tree)")


if __name__ == "__main__":
    main()
