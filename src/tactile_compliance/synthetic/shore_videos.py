"""Synthetic Shore-hardness press videos, named like the Yuan et al. (2017) dataset.

See docs/synthetic.md, "Shore-hardness press videos" (the hardness cue and the
measurements behind :data:`SILICONE_MAX_STRAIN`, :data:`STOP_DEPTH_MM` and one sensor).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from tactile_compliance.outputs import PARTIAL_PREFIX, claim_output_dir, commit_path
from tactile_compliance.synthetic.generate import GenerationError, GenerationReport
from tactile_compliance.synthetic.geometry import (
    PadGrid,
    ShapeSpec,
    sag_map,
    sample_pose,
    sample_shape,
)
from tactile_compliance.synthetic.mechanics import (
    GelModel,
    ObjectMechanics,
    force_curve,
    gel_compression_fields,
)
from tactile_compliance.synthetic.render import (
    SensorLook,
    gel_height_maps,
    render_frames,
    render_size,
    sample_sensor_look,
    to_stored_size,
)
from tactile_compliance.synthetic.rng import stream

__all__ = ["SHAPE_FAMILIES", "generate_shore_videos", "shore_video_name"]

SHAPE_FAMILIES = ("BASIC", "CYLINDER", "FLAT", "EDGE", "CORNER", "MOULD")
HARDNESS_RANGE = (8, 87)
"""Shore 00 hardness range of the samples [-]."""

_FPS = 30.0

SILICONE_MAX_STRAIN = 3.0
"""Saturating compressive strain of the silicone samples in the mechanics [-].

The samples are solid, nearly incompressible (nu = 0.49) silicone blocks: under the
sensor they flow sideways instead of densifying, and an elastomer stays close to linear
(Hertz) in indentation to depths of a good fraction of the contact radius. The
foundation's cap ``delta_o <= l_o eps_o`` is meant for foams and hollow objects; the
earlier 0.5 made soft samples bottom out ~3 mm into the press, after which the gel took
all the remaining interference and printed a soft sample as deeply as a hard one (the
mechanics' object share fell, the videos lost the hardness cue). 3.0 leaves a mild
stiffening, at most x1.5 within the stop depth below (foundation strain <= ~1)."""

STOP_DEPTH_MM = (3.0, 6.0)
"""Range of the approach [mm] at which a hand stops pressing a sample that gives way
(15-30 % of the 20 mm block); hard samples reach the target force long before."""

LIGHT_DRIFT = 0.05
"""Relative sigma of the sensor's LED brightness between presses (warm-up, sessions) [-]."""


def shore_video_name(shape: str, hardness: int, press: int) -> str:
    """``{SHAPE}_{hardness:02d}_{n}.avi``."""
    return f"{shape}_{hardness:02d}_{press}.avi"


def _geometry(family: str, rng: np.random.Generator) -> ShapeSpec:
    if family == "BASIC":
        return sample_shape("Sphere", rng, radius_mm=float(rng.uniform(8.0, 25.0)))
    if family == "CYLINDER":
        return sample_shape("Cylinder", rng, radius_mm=float(rng.uniform(4.0, 20.0)))
    if family == "FLAT":
        return sample_shape("Rectangular", rng)
    if family == "EDGE":
        spec = sample_shape("Hex", rng)
        spec.params["hex_mode"] = "corners"
        return spec
    return sample_shape("Irregular", rng)


@dataclass(frozen=True)
class _Sensor:
    """The one GelSight that recorded every press of a dataset.

    Attributes:
        gel: the sensor's elastomer (its thickness is fixed by the sensor's build).
        look: the sensor's appearance (background, lights, markers).
        brighten: grey levels gained per mm of imprint where the pressed membrane
            lights up, before the per-press lighting drift [1/mm].
    """

    gel: GelModel
    look: SensorLook
    brighten: float


def _sensor(seed: int) -> _Sensor:
    """Draw the dataset's sensor once per seed.

    Yuan et al. recorded all presses with one GelSight, so its gel thickness, lighting
    and membrane are constants of the dataset, not nuisances of each press. Drawing
    them per press (as this generator once did) made the imprint's brightness a random
    +-27 % gain and its depth scale a random gel, which drowned the hardness cue
    (docs/synthetic.md, Shore section). The per-press lighting drift stays (see
    :func:`_press_video`).
    """
    rng = stream(seed, "shore-sensor")
    gel = GelModel(thickness_mm=float(rng.uniform(1.5, 3.0)))
    look = sample_sensor_look(stream(seed, "shore-sensor", "look"), markers=True)
    return _Sensor(gel=gel, look=look, brighten=float(rng.uniform(40.0, 70.0)))


def _press_video(
    spec: ShapeSpec,
    modulus_pa: float,
    seed: int,
    key: tuple[object, ...],
    size: tuple[int, int],
    sensor: _Sensor,
) -> np.ndarray:
    """Raw BGR frames (T, H, W, 3) of one press."""
    rng = stream(seed, *key, "press")
    gel = sensor.gel
    obj = ObjectMechanics(
        modulus_pa=modulus_pa, poisson=0.49, size_mm=20.0, max_strain=SILICONE_MAX_STRAIN
    )
    grid = PadGrid(0.5)
    pose = sample_pose(rng, spec.kind)
    sag = sag_map(spec, grid, pose)
    curve = force_curve(sag, gel, obj, grid, max_force_n=30.0)
    # The hand aims at a 5-25 N press but stops early when the sample gives way: a
    # person does not squash a 20 mm block (the mechanics' foundation would let a very
    # soft sample take a 25 N press by sinking up to 16 mm, 4/5 of its height). The press
    # ends at the target force or at the stop depth, whichever comes first.
    target_n = float(rng.uniform(5.0, 25.0))
    stop_mm = float(rng.uniform(*STOP_DEPTH_MM))
    peak = min(target_n, float(np.interp(stop_mm, curve.approaches_mm, curve.forces_n)))
    n_pre, n_up, n_hold, n_down, n_post = (
        int(rng.integers(3, 7)),
        int(rng.integers(8, 20)),
        int(rng.integers(2, 6)),
        int(rng.integers(6, 14)),
        int(rng.integers(2, 5)),
    )
    up = np.sin(0.5 * np.pi * (np.arange(1, n_up + 1) / n_up)) ** 2
    down = np.cos(0.5 * np.pi * (np.arange(1, n_down + 1) / n_down)) ** 2
    hold = np.ones(n_hold) * (1 + rng.normal(0, 0.01, n_hold))
    profile = np.concatenate([np.zeros(n_pre), up, hold, down, np.zeros(n_post)])
    force = peak * profile
    approach = np.where(force > 0, curve.approach_at(np.maximum(force, 1e-9)), 0.0)
    fields = gel_compression_fields(sag, gel, obj, grid, approach)
    height, _ = gel_height_maps(fields, grid, render_size(size), gel.thickness_mm)
    # Pressed membrane brightens on this sensor (so the deepest press is the brightest).
    # Its lighting is steadier than the Wedge's (small frame-to-frame drift); between
    # presses the LEDs drift by a few per cent.
    brighten = -sensor.brighten * float(1.0 + rng.normal(0.0, LIGHT_DRIFT))
    look = replace(
        sensor.look,
        darkening=(brighten, brighten, brighten),
        drift=(0.0005, 0.1),
        jpeg_quality=0,
        _cache=sensor.look._cache,
    )
    return to_stored_size(render_frames(height, look, stream(seed, *key, "noise")), size)


def generate_shore_videos(
    out_dir: str | Path,
    *,
    n_objects: int = 40,
    presses_per_object: int = 3,
    seed: int = 0,
    image_size: tuple[int, int] = (250, 350),
    progress: bool = True,
) -> GenerationReport:
    """Write press videos named like the Shore-hardness dataset.

    One ``{SHAPE}_{hardness:02d}_{n}.avi`` per press (MJPG, 30 fps, raw BGR camera
    frames, as OpenCV writes them), each written under a hidden name and renamed into
    place when complete.

    Args:
        out_dir: output directory (created). Existing videos are kept (resume).
        n_objects: silicone samples; each gets a unique (shape family, hardness) pair.
        presses_per_object: videos per sample.
        seed: base seed (>= 0).
        image_size: frame size (H, W) [px].
        progress: show a progress bar.

    Returns:
        A :class:`GenerationReport` (``grasps`` and ``samples`` count presses/videos).
    """
    from tactile_compliance.physics.shore import shore00_to_modulus_pa
    from tactile_compliance.progress import progress_bar

    start = time.perf_counter()
    n_pairs = len(SHAPE_FAMILIES) * (HARDNESS_RANGE[1] - HARDNESS_RANGE[0] + 1)
    if not 1 <= n_objects <= n_pairs:
        raise GenerationError(f"n_objects must be in [1, {n_pairs}], got {n_objects}")
    if presses_per_object < 1:
        raise GenerationError(f"presses_per_object must be >= 1, got {presses_per_object}")
    if seed < 0:
        raise GenerationError(f"seed must be >= 0, got {seed}")
    height, width = (int(v) for v in image_size)
    if height % 2 or width % 2:  # the MJPG codec would silently drop the odd row/column
        raise GenerationError(f"image_size must be even for MJPG videos, got {height}x{width}")
    out = claim_output_dir(out_dir, "simulate shore-videos")
    for partial in out.glob(f"{PARTIAL_PREFIX}*"):  # leftovers of an interrupted run
        partial.unlink()
    # Unique (family, hardness) pairs: object i takes the i-th of a seeded permutation
    # whose order depends on the seed only (a subset gives the same first objects).
    order = stream(seed, "shore-objects").permutation(n_pairs)
    report = GenerationReport(out_dir=out, objects_total=n_objects, workers=1)
    sensor = _sensor(seed)
    total = n_objects * presses_per_object
    with progress_bar("rendering press videos", total, progress) as advance:
        for i in range(n_objects):
            pair = int(order[i])
            family = SHAPE_FAMILIES[pair % len(SHAPE_FAMILIES)]
            hardness = HARDNESS_RANGE[0] + pair // len(SHAPE_FAMILIES)
            modulus = float(shore00_to_modulus_pa(hardness))
            spec = _geometry(family, stream(seed, "shore", family, hardness, "geometry"))
            written = 0
            for n in range(1, presses_per_object + 1):
                path = out / shore_video_name(family, hardness, n)
                if path.exists():
                    advance(1)
                    continue
                key = ("shore", family, hardness, n)
                frames = _press_video(spec, modulus, seed, key, (height, width), sensor)
                partial = path.with_name(f"{PARTIAL_PREFIX}{path.name}")
                writer = cv2.VideoWriter(
                    str(partial), cv2.VideoWriter_fourcc(*"MJPG"), _FPS, (width, height)
                )
                if not writer.isOpened():
                    raise GenerationError(f"cannot open a video writer for {partial}")
                for frame in frames:
                    writer.write(frame)
                writer.release()
                commit_path(partial, path)
                written += 1
                report.samples += 1
                report.grasps += 1
                advance(1)
            if written:
                report.objects_written += 1
            else:
                report.objects_existing += 1
    report.seconds = time.perf_counter() - start
    return report
