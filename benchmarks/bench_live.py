"""What one frame costs on the live path (`tactile-compliance live`), stage by stage.

Stages timed per frame (median of ``--runs`` repetitions, milliseconds):

* ``mini_geometry``: a 3280 x 2464 GelSight Mini frame cropped 1/7 per side and resized
  to 320 x 240 (``MINI_GEOMETRY.apply``);
* ``wedge_geometry``: a 640 x 480 Wedge frame warped to 400 x 300 and cropped to 350 x 250;
* ``depth_240x320`` / ``depth_250x350``: difference image + photometric depth
  (``difference_images`` + ``reconstruct_depth``), what ``live`` adds per frame for
  checkpoints that use the analytical estimates;
* ``live_grasp``: a whole synthetic grasp at 250 x 350 replayed from an MJPG video through
  ``live_estimates`` with a random-weight Top10NN (inputs ALL, frames resized to the
  model's ``--model-size``), reported per frame and as the grasp's wall time against its
  duration at 30 fps (a real-time factor below 1 keeps up with the camera).

Usage::

    python benchmarks/bench_live.py --threads 2 --runs 20
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
import torch

from tactile_compliance.acquisition.readings import Readings
from tactile_compliance.acquisition.sensors import MINI_GEOMETRY, WEDGE_GEOMETRY, open_source
from tactile_compliance.data.image_ops import difference_images
from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.data.photometric import reconstruct_depth
from tactile_compliance.inference.estimator import ComplianceEstimator
from tactile_compliance.inference.live import live_estimates
from tactile_compliance.models import create_model
from tactile_compliance.runs.run_inputs import RunInputs


def _median_ms(fn, runs: int) -> float:
    fn()  # warm-up
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return 1000.0 * float(np.median(times))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--model-size", type=int, nargs=2, default=[250, 350])
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    cv2.setNumThreads(args.threads)
    rng = np.random.default_rng(0)
    print(f"threads {args.threads}, load average {os.getloadavg()[0]:.2f}")

    mini = rng.integers(0, 255, (2464, 3280, 3), dtype=np.uint8)
    wedge = rng.integers(0, 255, (480, 640, 3), dtype=np.uint8)
    print(f"mini_geometry   {_median_ms(lambda: MINI_GEOMETRY.apply(mini), args.runs):7.2f} ms")
    print(f"wedge_geometry  {_median_ms(lambda: WEDGE_GEOMETRY.apply(wedge), args.runs):7.2f} ms")
    for size in ((240, 320), (250, 350)):
        frame = rng.integers(100, 156, (*size, 3), dtype=np.uint8)
        ref = rng.integers(100, 156, (*size, 3), dtype=np.uint8)
        ms = _median_ms(
            lambda f=frame, r=ref: reconstruct_depth(difference_images(f[None], r)), args.runs
        )
        print(f"depth_{size[0]}x{size[1]}   {ms:7.2f} ms")

    from tactile_compliance.synthetic.grasp import SimulationOptions, make_context
    from tactile_compliance.synthetic.objects import default_objects
    from tactile_compliance.synthetic.trajectories import camera_recording

    spec = default_objects(3, seed=4)[1]
    recording = camera_recording(make_context(spec, 4, SimulationOptions()), 0)
    torch.manual_seed(0)
    model = create_model("top10nn", inputs="ALL")
    estimator = ComplianceEstimator(
        model,
        RunInputs(
            tuple(args.model_size), tuple(args.model_size), NormalisationConstants(), model.inputs
        ),
    )
    with tempfile.TemporaryDirectory() as tmp:
        video = Path(tmp) / "grasp.avi"
        h, w = recording.frames.shape[1:3]
        writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (w, h))
        for frame in recording.frames:
            writer.write(frame)
        writer.release()
        times = np.arange(len(recording.frames)) / 30.0
        readings = Readings(times, recording.force_n, recording.width_m)
        start = time.perf_counter()
        with open_source(f"video:{video}") as source:
            events = list(live_estimates([estimator], source, readings))
        wall = time.perf_counter() - start
    frames = events[-1]["frames_seen"]
    print(
        f"live_grasp      {1000 * wall / frames:7.2f} ms/frame over {frames} frames "
        f"({len(events)} estimates, model {args.model_size[0]}x{args.model_size[1]}); "
        f"{wall:.2f} s for {frames / 30.0:.2f} s of grasp (real-time factor "
        f"{wall / (frames / 30.0):.2f})"
    )


if __name__ == "__main__":
    main()
