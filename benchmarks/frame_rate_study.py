"""Frame selection at 18, 25, 30 and 60 fps: does the stream pick the same moments?

For simulated grasps (``default_objects(N, seed)``, grasps 0 and 1 of each object), the
generator renders the same grasp as cameras at each rate would see it
(``synthetic_trajectories(..., fps=)``). Each recording is streamed through
:class:`StreamingEstimator` with timestamps. Reported per grasp and rate:

* ``dt_ms``: selected frame times minus the moments the dataset's rule means
  (``linspace(t_start, t_peak, 3)`` on the generator's force curve at 0.1 ms), and the
  frame period;
* the final estimate (log10 Pa) of an untrained ImageFW Res-Tf, and its spread over the
  rates;
* ``window=9`` (frames, no timestamps) against ``window_s=8/30`` (seconds): the spread of
  the first selected frame's time over the rates.

Run (1 minute on 2 shared CPU cores, load average 7-10)::

    python benchmarks/frame_rate_study.py --objects 6 --json fps.json

A research script, not part of the installed package; the test is
``tests/test_streaming_timestamps.py``.
"""

from __future__ import annotations

import argparse
import json
from typing import Any

import numpy as np
import torch

from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.inference import (
    ComplianceEstimator,
    StreamingEstimator,
    select_frame_indices,
)
from tactile_compliance.models import create_model
from tactile_compliance.runs.run_inputs import RunInputs
from tactile_compliance.synthetic.grasp import SimulationOptions, make_context, simulate_grasp
from tactile_compliance.synthetic.objects import default_objects
from tactile_compliance.synthetic.trajectories import synthetic_trajectories

RATES_FPS = (18.0, 25.0, 30.0, 60.0)
SIZE = (48, 64)


def true_moments_s(spec: Any, seed: int, grasp: int) -> np.ndarray | None:
    """``linspace(t_start, t_peak, 3)`` on the generator's force curve (0.1 ms steps)."""
    timeline = simulate_grasp(make_context(spec, seed, SimulationOptions(image_size=SIZE)), grasp)
    times, force_n = timeline.timeline.times_s, timeline.timeline.force_n
    t = np.arange(times[0], times[-1], 1e-4)
    force = np.interp(t, times, force_n)
    if not np.any(force >= 5.0):
        return None
    t_start = t[np.argmax(force >= 5.0)]
    after = t >= t_start
    t_peak = t[np.argmax(after & (force >= 0.975 * force[after].max()))]
    return np.linspace(t_start, t_peak, 3)


def study(n_objects: int, seed: int) -> list[dict[str, Any]]:
    torch.set_num_threads(1)
    torch.manual_seed(0)
    model = create_model("res_tf", inputs="ImageFW", num_layers=1, embedding_dim=64, output_dim=64)
    estimator = ComplianceEstimator(
        model, RunInputs((32, 32), (32, 32), NormalisationConstants(), model.inputs)
    )
    rows = []
    for spec in default_objects(n_objects, seed=seed):
        for grasp in (0, 1):
            moments = true_moments_s(spec, seed, grasp)
            if moments is None:
                continue
            row: dict[str, Any] = {"object": spec.name, "grasp": grasp, "rates": {}}
            first_by_count, first_by_time = [], []
            for fps in RATES_FPS:
                found = list(
                    synthetic_trajectories(
                        [(spec.name, grasp)],
                        n_objects=n_objects,
                        seed=seed,
                        image_size=SIZE,
                        fps=fps,
                    )
                )
                if not found:
                    break
                rec = found[0]
                stream = StreamingEstimator(estimator)
                final = None
                for frame, f, w, t in zip(
                    rec.frames, rec.force_n, rec.width_m, rec.times_s, strict=True
                ):
                    final = stream.update(frame, f, w, timestamp_s=t) or final
                final = final if final is not None and final.final else stream.finish()
                row["rates"][fps] = {
                    "dt_ms": ((np.array(final.frame_times_s) - moments) * 1e3).round(1).tolist(),
                    "period_ms": round(1e3 / fps, 1),
                    "log10_modulus_pa": final.log10_modulus_pa,
                }
                by_count = select_frame_indices(rec.force_n, window=9)
                first_by_count.append(float(rec.times_s[by_count.indices[0]]))
                by_time = select_frame_indices(
                    rec.force_n, timestamps_s=rec.times_s, window_s=8 / 30
                )
                first_by_time.append(by_time.times_s[0])
            if len(row["rates"]) < len(RATES_FPS):
                continue  # the generator rejected the grasp
            estimates = [r["log10_modulus_pa"] for r in row["rates"].values()]
            row["estimate_spread_decades"] = float(np.ptp(estimates))
            row["worst_dt_over_period"] = max(
                max(abs(d) for d in r["dt_ms"]) / r["period_ms"] for r in row["rates"].values()
            )
            row["window9_first_frame_spread_ms"] = float(np.ptp(first_by_count) * 1e3)
            row["window_s_first_frame_spread_ms"] = float(np.ptp(first_by_time) * 1e3)
            rows.append(row)
            print(
                f"{spec.name} grasp {grasp}: worst |dt| / period "
                f"{row['worst_dt_over_period']:.2f}, estimate spread "
                f"{row['estimate_spread_decades']:.4f} decades, first frame spread "
                f"window=9 {row['window9_first_frame_spread_ms']:.0f} ms, window_s "
                f"{row['window_s_first_frame_spread_ms']:.0f} ms",
                flush=True,
            )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--objects", type=int, default=6)
    parser.add_argument("--seed", type=int, default=4)
    parser.add_argument("--json", default=None, help="Write the rows to this file.")
    args = parser.parse_args()
    rows = study(args.objects, args.seed)
    worst_ms = max(
        max(abs(d) for d in r["dt_ms"]) for row in rows for r in row["rates"].values() if r
    )
    print(
        f"{len(rows)} grasps: worst |dt| {worst_ms:.1f} ms, worst |dt| / period "
        f"{max(r['worst_dt_over_period'] for r in rows):.2f}, worst estimate spread "
        f"{max(r['estimate_spread_decades'] for r in rows):.4f} decades, first frame spread "
        f"window=9 up to {max(r['window9_first_frame_spread_ms'] for r in rows):.0f} ms, "
        f"window_s up to {max(r['window_s_first_frame_spread_ms'] for r in rows):.0f} ms"
    )
    if args.json:
        with open(args.json, "w", encoding="utf-8") as handle:
            json.dump(rows, handle, indent=1)


if __name__ == "__main__":
    main()
