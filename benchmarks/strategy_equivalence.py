"""Do the paper's four input strategies predict what they predicted before a change?

Trains every (model, strategy) pair of the paper on the toy store of the tests, a few
epochs each with a fixed seed, and writes the test predictions (log10 Pa) of each run to
one ``.npz``. Run it once on the commit before a change and once after, then compare:

    PYTHONPATH=OLD/src python benchmarks/strategy_equivalence.py --out before.npz
    python benchmarks/strategy_equivalence.py --out after.npz
    python benchmarks/strategy_equivalence.py --compare before.npz after.npz

``--compare`` prints the largest difference per run in decades and exits 1 when one
exceeds ``--tolerance`` (1e-6 decades). A few minutes on 2 CPU cores.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

PAIRS = [
    (model, inputs)
    for model in ("top10nn", "res_tf", "vgg_lstm")
    for inputs in ("Image", "ImageF", "ImageFW", "ALL")
]


def run(out: Path, epochs: int) -> None:
    import torch

    from tactile_compliance.training.train import train
    from toy_store import make_toy_store, tiny_run_config

    torch.set_num_threads(2)
    results: dict[str, np.ndarray] = {}
    with tempfile.TemporaryDirectory() as tmp:
        store = make_toy_store(Path(tmp) / "store", n_objects=8, grasps=2, size=(32, 32))
        for model, inputs in PAIRS:
            extra = [f"inputs={inputs}", f"training.max_epochs={epochs}", "training.lr=1e-3"]
            if model == "vgg_lstm":  # VGG16 needs 32 px; keep the run small
                extra += ["training.limit_batches=2", "data.image_size=[32,32]"]
            else:
                extra += ["data.image_size=[72,72]"] if model == "top10nn" else []
            cfg = tiny_run_config(store.path, Path(tmp) / "runs", model, extra)
            run_dir = Path(tmp) / "runs" / f"{model}-{inputs}"
            train(cfg, run_dir=run_dir, progress=False)
            frame = __import__("pandas").read_csv(run_dir / "predictions.csv")
            results[f"{model}/{inputs}"] = np.log10(frame["pred_pa"].to_numpy(np.float64))
            print(f"{model:9s} {inputs:8s} {len(frame)} predictions", flush=True)
    np.savez(out, **results)
    print(f"wrote {out}")


def compare(before: Path, after: Path, tolerance: float) -> int:
    a, b = np.load(before), np.load(after)
    worst = 0.0
    for key in sorted(a.files):
        if key not in b.files:
            print(f"{key:20s} missing in {after}")
            return 1
        diff = float(np.max(np.abs(a[key] - b[key]))) if a[key].size else 0.0
        worst = max(worst, diff)
        print(f"{key:20s} max |after - before| = {diff:.3g} decades ({a[key].size} grasps)")
    verdict = "OK" if worst <= tolerance else "DIFFERENT"
    print(f"worst {worst:.3g} decades (tolerance {tolerance:g}): {verdict}")
    return 0 if worst <= tolerance else 1


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path)
    parser.add_argument("--epochs", type=int, default=2)
    parser.add_argument("--compare", nargs=2, type=Path, metavar=("BEFORE", "AFTER"))
    parser.add_argument("--tolerance", type=float, default=1e-6)
    args = parser.parse_args()
    if args.compare:
        return compare(*args.compare, args.tolerance)
    if args.out is None:
        parser.error("give --out FILE or --compare BEFORE AFTER")
    run(args.out, args.epochs)
    return 0


if __name__ == "__main__":
    sys.exit(main())
