"""Two inference studies on synthetic data: the streaming window and ensemble calibration.

1. **Window study** (the paper's future work "estimate from the last n frames instead of
   the whole trajectory"): for held-out grasps, the whole recording is rendered frame by
   frame with the synthetic generator, fed to :class:`StreamingEstimator` with
   ``window=None`` (the dataset's rule) and with ``window=n``, and the final and the
   first (earliest) estimates are compared with the truth and with the full-trajectory
   estimate.
2. **Ensemble calibration**: the seeds of one configuration, trained on one shared split,
   form an ensemble; the coverage of its 80 % interval is measured on the test split
   (:func:`~tactile_compliance.inference.ensemble.ensemble_calibration`).

Run everything (generation, import, 5 training runs, both studies; 40-55 minutes on 2
shared CPU cores with the defaults, mostly training)::

    python benchmarks/inference_studies.py --workdir study --json study.json

Whole recordings come from :func:`tactile_compliance.synthetic.trajectories.synthetic_trajectories`.
This is a research script, not part of the installed package.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from tactile_compliance.inference.ensemble import ensemble_calibration
from tactile_compliance.inference.estimator import ComplianceEstimator
from tactile_compliance.inference.streaming import StreamingEstimator
from tactile_compliance.synthetic.trajectories import GraspTrajectory, synthetic_trajectories

__all__ = ["run_studies", "summarise_window_study", "window_study"]


def window_study(
    estimator: ComplianceEstimator,
    trajectories: Sequence[GraspTrajectory],
    windows: Sequence[int | None] = (None, 3, 5, 8, 12),
) -> pd.DataFrame:
    """Stream every trajectory with every window; one row per (grasp, window).

    Columns: object, grasp, window (0 = whole trajectory), true_log10, final_log10 and
    first_log10 (the final and the earliest estimate), first_frames_after_onset (how many
    frames after contact the first estimate came), final_frames_after_onset, span
    (frames between the first and last selected frame).
    """
    if "rig_estimates" in estimator.required_inputs:
        # The trajectories carry the dataset's two estimates, not the rig-corrected pair.
        raise ValueError("the window study streams the dataset's estimates; FWR models need depth")
    rows = []
    needs_estimates = "estimates" in estimator.required_inputs
    for trajectory in trajectories:
        if needs_estimates and not np.all(np.isfinite(trajectory.estimates_pa)):
            continue
        for window in windows:
            stream = StreamingEstimator(
                estimator,
                window=window,
                estimates_pa=trajectory.estimates_pa if needs_estimates else None,
            )
            emitted = []
            for frame, force, width in zip(
                trajectory.frames, trajectory.force_n, trajectory.width_m, strict=True
            ):
                estimate = stream.update(frame, force, width)
                if estimate is not None:
                    emitted.append(estimate)
            final = stream.finish() if not (emitted and emitted[-1].final) else emitted[-1]
            if final is None:
                continue
            first = emitted[0]
            rows.append(
                {
                    "object": trajectory.object,
                    "grasp": trajectory.grasp,
                    "window": 0 if window is None else int(window),
                    "true_log10": float(np.log10(trajectory.modulus_pa)),
                    "final_log10": final.log10_modulus_pa,
                    "first_log10": first.log10_modulus_pa,
                    "first_frames_after_onset": first.frames_seen - 1 - first.onset_frame,
                    "final_frames_after_onset": final.peak_frame - final.onset_frame,
                    "span": final.frame_indices[2] - final.frame_indices[0],
                    "refinements": len(emitted),
                }
            )
    return pd.DataFrame(rows)


def summarise_window_study(table: pd.DataFrame) -> pd.DataFrame:
    """Per window: errors vs truth (final and first estimate) and vs the full trajectory."""
    full = table[table["window"] == 0].set_index(["object", "grasp"])["final_log10"]
    out = []
    for window, group in table.groupby("window", sort=True):
        g = group.set_index(["object", "grasp"])
        err = g["final_log10"] - g["true_log10"]
        first_err = g["first_log10"] - g["true_log10"]
        vs_full = g["final_log10"] - full.reindex(g.index)
        out.append(
            {
                "window": "full" if window == 0 else int(window),
                "grasps": len(g),
                "final_mae_decades": float(err.abs().mean()),
                "final_log10_accuracy": float((err.abs() <= 1).mean()),
                "final_vs_full_mean_abs_decades": float(vs_full.abs().mean()),
                "final_vs_full_max_abs_decades": float(vs_full.abs().max()),
                "first_mae_decades": float(first_err.abs().mean()),
                "first_frames_after_onset": float(g["first_frames_after_onset"].mean()),
                "mean_span_frames": float(g["span"].mean()),
            }
        )
    return pd.DataFrame(out)


# ---------------------------------------------------------------------- end to end
def run_studies(
    workdir: str | Path,
    *,
    n_objects: int = 40,
    seed: int = 0,
    image_size: tuple[int, int] = (100, 140),
    model_size: tuple[int, int] = (72, 72),
    n_seeds: int = 5,
    max_epochs: int = 15,
    windows: Sequence[int | None] = (None, 3, 5, 8, 12),
    max_grasps: int = 60,
    level: float = 0.8,
    progress: bool = False,
) -> dict[str, Any]:
    """Generate a synthetic dataset, train ``n_seeds`` Top10NN ImageFW runs on one split,
    and run both studies on the test split. Everything lands in ``workdir``."""
    from tactile_compliance.config import load_config
    from tactile_compliance.data.burgess import import_burgess
    from tactile_compliance.data.splits import Split
    from tactile_compliance.data.store import GraspStore
    from tactile_compliance.synthetic import generate_burgess_tree
    from tactile_compliance.training.train import train

    started = time.perf_counter()
    workdir = Path(workdir)
    tree, store_dir = workdir / "tree", workdir / "store"
    generate_burgess_tree(
        tree, n_objects=n_objects, seed=seed, image_size=image_size, progress=progress
    )
    if not store_dir.exists():
        import_burgess(tree, store_dir, source_name="synthetic", progress=progress)
    store = GraspStore.open(store_dir)
    run_dirs = []
    for run_seed in range(n_seeds):
        cfg = load_config(
            "default",
            [
                f"data.store={store_dir}",
                f"output_dir={workdir / 'runs'}",
                "model.name=top10nn",
                "inputs=ImageFW",
                f"data.image_size=[{model_size[0]}, {model_size[1]}]",
                "augmentation.enabled=false",
                f"training.max_epochs={max_epochs}",
                "training.lr=1e-3",
                "training.batch_size=32",
                "split.seed=0",
                f"seed={run_seed}",
            ],
        )
        result = train(cfg, progress=progress)
        run_dirs.append(Path(result["run_dir"]))

    calibration = ensemble_calibration(run_dirs, level=level)

    split = Split.load(run_dirs[0] / "split.json")
    test_rows = store.samples.iloc[split.test_ids]
    grasps = sorted(
        {(str(o), int(g)) for o, g in zip(test_rows["object"], test_rows["grasp"], strict=True)}
    )[:max_grasps]
    trajectories = list(
        synthetic_trajectories(grasps, n_objects=n_objects, seed=seed, image_size=image_size)
    )
    estimator = ComplianceEstimator.from_checkpoint(run_dirs[0])
    table = window_study(estimator, trajectories, windows)
    summary = summarise_window_study(table)
    return {
        "data": {
            "source": "synthetic (generate_burgess_tree, default mix)",
            "n_objects": n_objects,
            "seed": seed,
            "image_size": list(image_size),
            "store_samples": len(store),
        },
        "model": {
            "name": "top10nn",
            "inputs": "ImageFW",
            "image_size": list(model_size),
            "max_epochs": max_epochs,
            "seeds": n_seeds,
            "backbone_weights": "none (random init)",
        },
        "ensemble_calibration": calibration,
        "window_study": {
            "grasps": len(trajectories),
            "mean_frames_per_recording": float(np.mean([len(t.frames) for t in trajectories]))
            if trajectories
            else 0.0,
            "summary": summary.to_dict(orient="records"),
        },
        "seconds": round(time.perf_counter() - started, 1),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="Streaming-window and ensemble studies.")
    parser.add_argument("--workdir", type=Path, required=True)
    parser.add_argument("--objects", type=int, default=40)
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--epochs", type=int, default=15)
    parser.add_argument("--max-grasps", type=int, default=60)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    report = run_studies(
        args.workdir,
        n_objects=args.objects,
        n_seeds=args.seeds,
        max_epochs=args.epochs,
        max_grasps=args.max_grasps,
        progress=False,
    )
    text = json.dumps(report, indent=2, default=float)
    if args.json is not None:
        args.json.write_text(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
