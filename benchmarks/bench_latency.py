"""Batch-1 CPU latency of every model in PyTorch and onnxruntime (p50 / p95).

For each model (random weights, default hyperparameters, inputs ALL) at the frame size
the presets use (Top10NN and Res-Tf: the store's 250 x 350; VGG-LSTM: its recommended
224 x 224), the script writes a self-describing checkpoint, exports it with
``export_onnx`` (parity checked) and times one grasp at a time:

* ``torch``: ``model(frames, force=F, width=W, estimates=E)`` on normalised tensors;
* ``onnxruntime``: the exported graph on the same tensors;
* ``predict_torch`` / ``predict_onnx``: ``ComplianceEstimator.predict`` /
  ``OnnxEstimator.predict`` end to end from uint8 frames (validation, normalisation,
  forward, read-back to Pa).

The four variants are timed round robin (interleaved), so drifting load from other
processes on a shared machine affects them alike; the load average is recorded.

Usage::

    python benchmarks/bench_latency.py                     # all models, 2 threads
    python benchmarks/bench_latency.py --models top10nn --runs 50 --threads 2 --json out.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.inference import ComplianceEstimator, OnnxEstimator, export_onnx
from tactile_compliance.inference.export import _example_inputs
from tactile_compliance.inference.onnx import _ort_session, onnx_input_names
from tactile_compliance.models import create_model
from tactile_compliance.runs.checkpoint import save_checkpoint
from tactile_compliance.runs.run_inputs import RunInputs

#: Frame size (H, W) px per model, as the presets use them (see the module docstring).
SIZES: dict[str, tuple[int, int]] = {
    "top10nn": (250, 350),
    "res_tf": (250, 350),
    "vgg_lstm": (224, 224),
}


def cpu_model() -> str:
    """The CPU's model name from ``lscpu`` (or platform as a fallback)."""
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, check=True).stdout
        for line in out.splitlines():
            if line.startswith("Model name:"):
                return line.split(":", 1)[1].strip()
    except (OSError, subprocess.CalledProcessError):
        pass
    return platform.processor() or "unknown"


def percentiles(times_s: list[float]) -> dict[str, float]:
    """p50 / p95 / mean in milliseconds."""
    ms = np.asarray(times_s) * 1e3
    return {
        "p50_ms": float(np.percentile(ms, 50)),
        "p95_ms": float(np.percentile(ms, 95)),
        "mean_ms": float(ms.mean()),
        "runs": int(ms.size),
    }


def time_interleaved(
    fns: dict[str, Any], runs: int, warmup: int, budget_s: float
) -> dict[str, list[float]]:
    """Wall time of each function, called in turn (round robin) ``runs`` times.

    Interleaving matters on a shared machine: load from other processes changes over
    minutes, and timing one variant after the other would attribute that drift to the
    variants. Stops early past ``budget_s`` once every variant has 10 calls.
    """
    for fn in fns.values():
        for _ in range(warmup):
            fn()
    times: dict[str, list[float]] = {name: [] for name in fns}
    started = time.perf_counter()
    for i in range(runs):
        names = list(fns)
        names = names[i % len(names) :] + names[: i % len(names)]  # rotate the order too
        for name in names:
            t0 = time.perf_counter()
            fns[name]()
            times[name].append(time.perf_counter() - t0)
        if time.perf_counter() - started > budget_s and i + 1 >= 10:
            break
    return times


def bench_model(
    name: str, workdir: Path, runs: int, warmup: int, threads: int, budget_s: float
) -> dict[str, Any]:
    size = SIZES[name]
    torch.manual_seed(0)
    model = create_model(name, inputs="ALL").eval()
    checkpoint = save_checkpoint(
        workdir / f"{name}.pt",
        model,
        run_inputs=RunInputs(size, size, NormalisationConstants(), model.inputs),
        config={},
        seed=0,
    )
    onnx_path = workdir / f"{name}.onnx"
    t0 = time.perf_counter()
    report = export_onnx(checkpoint, onnx_path)
    export_s = time.perf_counter() - t0

    names = onnx_input_names("ALL")
    inputs = _example_inputs(names, 1, size)
    kwargs = dict(zip(names[1:], inputs[1:], strict=True))
    session = _ort_session(onnx_path, threads)
    feed = {n: t.numpy() for n, t in zip(names, inputs, strict=True)}

    def torch_call() -> None:
        with torch.inference_mode():
            model(inputs[0], **kwargs)

    def ort_call() -> None:
        session.run(None, feed)

    estimator = ComplianceEstimator.from_checkpoint(checkpoint)
    rng = np.random.default_rng(0)
    frames = rng.integers(110, 146, size=(3, *size, 3), dtype=np.uint8)
    scalars = {"force": [8.0, 30.0, 58.0], "width": [0.05, 0.048, 0.046], "estimates": [2e5, 4e5]}

    def predict_call() -> None:
        estimator.predict(frames, **scalars)

    onnx_estimator = OnnxEstimator(onnx_path, threads=threads)

    def onnx_predict_call() -> None:
        onnx_estimator.predict(frames, **scalars)

    times = time_interleaved(
        {
            "torch": torch_call,
            "onnxruntime": ort_call,
            "predict_torch": predict_call,
            "predict_onnx": onnx_predict_call,
        },
        runs,
        warmup,
        budget_s,
    )
    result = {
        "model": name,
        "image_size": list(size),
        "parameters_m": sum(p.numel() for p in model.parameters()) / 1e6,
        "onnx_max_abs_diff": report["max_abs_diff"],
        "onnx_file_mb": report["file_size_bytes"] / 1e6,
        "export_s": export_s,
        **{variant: percentiles(values) for variant, values in times.items()},
    }
    onnx_path.unlink(missing_ok=True)
    checkpoint.unlink(missing_ok=True)
    return result


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=list(SIZES), choices=list(SIZES))
    parser.add_argument("--runs", type=int, default=50, help="timed calls per measurement")
    parser.add_argument("--warmup", type=int, default=5)
    parser.add_argument("--threads", type=int, default=2, help="torch and onnxruntime threads")
    parser.add_argument(
        "--budget-s",
        type=float,
        default=240.0,
        help="stop a model's measurements after this long (at least 10 calls)",
    )
    parser.add_argument("--json", type=Path, default=None, help="write the results here")
    args = parser.parse_args(argv)

    torch.set_num_threads(args.threads)
    machine = {
        "cpu": cpu_model(),
        "threads": args.threads,
        "python": platform.python_version(),
        "torch": torch.__version__,
    }
    import onnxruntime

    machine["onnxruntime"] = onnxruntime.__version__
    # On a shared machine other processes inflate the numbers: record the load.
    machine["load_average_before"] = [round(v, 2) for v in os.getloadavg()]
    print(f"# {machine}", flush=True)
    results = []
    with tempfile.TemporaryDirectory(prefix="bench-latency-") as tmp:
        for name in args.models:
            r = bench_model(name, Path(tmp), args.runs, args.warmup, args.threads, args.budget_s)
            results.append(r)
            h, w = r["image_size"]
            print(
                f"{name:<9} {h}x{w}  torch p50 {r['torch']['p50_ms']:.1f} / p95 "
                f"{r['torch']['p95_ms']:.1f} ms | onnxruntime p50 {r['onnxruntime']['p50_ms']:.1f}"
                f" / p95 {r['onnxruntime']['p95_ms']:.1f} ms | predict() p50 "
                f"{r['predict_torch']['p50_ms']:.1f} ms (onnx {r['predict_onnx']['p50_ms']:.1f})"
                f" | parity {r['onnx_max_abs_diff']:.2g}",
                flush=True,
            )
    machine["load_average_after"] = [round(v, 2) for v in os.getloadavg()]
    print(f"# load average after: {machine['load_average_after']}")
    if args.json is not None:
        args.json.write_text(json.dumps({"machine": machine, "results": results}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
