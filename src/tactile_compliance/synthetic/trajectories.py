"""Whole grasp recordings from the synthetic generator, for streaming estimators.

The generator stores three frames per grasp; this re-simulates a stored grasp from its
(seed, object, grasp) key and renders every frame. See docs/synthetic.md, "Usage".
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["CameraRecording", "GraspTrajectory", "camera_recording", "synthetic_trajectories"]


@dataclass
class GraspTrajectory:
    """One whole grasp recording (markerless finger).

    Attributes:
        object: object name; grasp: grasp number.
        modulus_pa: ground truth (Pa).
        frames: (T, H, W, 3) uint8 RGB difference images (store encoding).
        force_n: (T,) measured normal force (N); width_m: (T,) measured width (m).
        estimates_pa: (elastic E, Hertz E*) of the grasp (Pa), NaN if not estimable.
        times_s: (T,) capture time of each frame (s).
    """

    object: str
    grasp: int
    modulus_pa: float
    frames: np.ndarray
    force_n: np.ndarray
    width_m: np.ndarray
    estimates_pa: np.ndarray
    times_s: np.ndarray | None = None


def synthetic_trajectories(
    grasps: Sequence[tuple[str, int]],
    *,
    n_objects: int,
    seed: int,
    image_size: tuple[int, int],
    fps: float | None = None,
    **options: Any,
) -> Iterator[GraspTrajectory]:
    """Re-simulate grasps of a ``generate_burgess_tree`` dataset and render every frame.

    The time series are exactly those of the stored grasps (same seed and keys); the
    frames are new draws of the same sensor noise. Grasps the generator rejected are
    left out.

    Args:
        grasps: (object name, grasp number) pairs, e.g. a run's test split.
        n_objects, seed, image_size, options: the generation's parameters (the default
            object mix; ``options`` are ``SimulationOptions`` fields).
        fps: None: the simulated frames (30 fps, ~2 ms jitter). A rate in frames/s: the
            same grasp seen by a camera at that constant rate over the same time span
            (``render_recording(fps=)``); the measured force is interpolated linearly
            between the simulated frames, the measured width is held from the last
            reading at or before each frame (the encoder's stair steps).
    """
    from tactile_compliance.data.store import frames_to_uint8
    from tactile_compliance.synthetic.grasp import (
        SimulationOptions,
        camera_times_s,
        make_context,
        render_recording,
    )
    from tactile_compliance.synthetic.objects import default_objects

    opt = SimulationOptions(image_size=tuple(image_size), **options)  # type: ignore[arg-type]
    specs = {s.name: s for s in default_objects(n_objects, seed)}
    contexts: dict[str, Any] = {}
    for name, grasp in grasps:
        if name not in specs:
            raise ValueError(f"object {name!r} is not in the default mix of {n_objects} objects")
        if name not in contexts:  # its texture canvases are drawn once per object
            contexts[name] = make_context(specs[name], seed, opt)
        ctx = contexts[name]
        result, diff_bgr = render_recording(ctx, int(grasp), finger=0, fps=fps)
        if not result.samples:
            continue  # the generator rejected this grasp too
        timeline = result.timeline
        times = np.asarray(timeline.times_s, dtype=np.float64)
        force = np.asarray(timeline.force_n, dtype=np.float64)
        width = np.asarray(timeline.width_m, dtype=np.float64)
        if fps is not None:
            frame_times = camera_times_s(times, fps)
            held = np.clip(np.searchsorted(times, frame_times, side="right") - 1, 0, None)
            times, force, width = frame_times, np.interp(frame_times, times, force), width[held]
        sample = result.samples[0]
        yield GraspTrajectory(
            object=name,
            grasp=int(grasp),
            modulus_pa=float(ctx.spec.modulus_pa),
            frames=frames_to_uint8(diff_bgr[..., ::-1]),  # BGR (OpenCV) -> RGB like the store
            force_n=force,
            width_m=width,
            estimates_pa=np.array([sample.elastic_estimate, sample.hertz_estimate]),
            times_s=times,
        )


@dataclass
class CameraRecording:
    """One grasp as the camera saw it (markerless or marker finger).

    Attributes:
        frames: (T, H, W, 3) uint8 BGR raw camera frames.
        reference: (H, W, 3) uint8 BGR no-contact frame of the same sensor (another
            noise draw: what a calibration would record).
        times_s: (T,) frame times [s] of the simulation (jittered around 1 / 30 s).
        force_n: (T,) measured force [N]; width_m: (T,) measured width [m].
        modulus_pa: the object's ground truth [Pa].
    """

    frames: np.ndarray
    reference: np.ndarray
    times_s: np.ndarray
    force_n: np.ndarray
    width_m: np.ndarray
    modulus_pa: float


def camera_recording(ctx: Any, grasp: int, finger: int = 0) -> CameraRecording:
    """Grasp ``grasp`` of an object context (``synthetic.grasp.make_context``) as raw frames.

    The frames are the rendered difference images put back on a no-contact frame:
    ``GaussianBlur11x11(reference) + 255 (diff - 0.5)``, rounded, so that differencing
    them against ``reference`` as the real pipeline does gives the rendered difference
    images back (to rounding and clipping).
    """
    import cv2

    from tactile_compliance.synthetic.grasp import render_recording
    from tactile_compliance.synthetic.render import reference_frame
    from tactile_compliance.synthetic.rng import stream

    result, diff_bgr = render_recording(ctx, int(grasp), finger=finger)
    size = tuple(diff_bgr.shape[1:3])
    rng = stream(ctx.seed, ctx.spec.name, "grasp", int(grasp), "camera-reference", finger)
    reference = reference_frame(ctx.session.looks[finger], size, rng)  # type: ignore[arg-type]
    blurred = cv2.GaussianBlur(reference, (11, 11), 0).astype(np.float32)
    raw = np.rint(blurred[None] + 255.0 * (diff_bgr.astype(np.float32) - 0.5))
    timeline = result.timeline
    return CameraRecording(
        frames=np.clip(raw, 0, 255).astype(np.uint8),
        reference=reference,
        times_s=np.asarray(timeline.times_s, dtype=np.float64),
        force_n=np.asarray(timeline.force_n, dtype=np.float64),
        width_m=np.asarray(timeline.width_m, dtype=np.float64),
        modulus_pa=float(ctx.spec.modulus_pa),
    )
