"""Simulate one grasp end to end: mechanics -> time series -> frames -> depth -> estimates.

See docs/synthetic.md, "One grasp, step by step".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import lru_cache

import numpy as np

from tactile_compliance.data.frame_selection import AugmentedSelection
from tactile_compliance.data.photometric import reconstruct_depth
from tactile_compliance.physics.dataset_estimates import (
    DATASET_CONSTANTS,
    DatasetEstimatorConstants,
    dataset_estimates_pa,
    dataset_force_press,
    dataset_press_window,
    interpolate_repeated_widths,
)
from tactile_compliance.synthetic.geometry import PadGrid, sag_map, sample_pose
from tactile_compliance.synthetic.mechanics import (
    ContactCurve,
    GelModel,
    ObjectMechanics,
    force_curve,
    gel_compression,
)
from tactile_compliance.synthetic.objects import ObjectSpec
from tactile_compliance.synthetic.render import (
    FULL_SIZE,
    SensorLook,
    difference_images,
    gel_height_maps,
    pixel_size_mm,
    reference_frame,
    render_frames,
    render_size,
    sample_edge_glow,
    sample_sensor_look,
    to_stored_size,
)
from tactile_compliance.synthetic.rng import stream
from tactile_compliance.synthetic.textures import texture_canvas, texture_window
from tactile_compliance.synthetic.timeseries import (
    DATASET_RIG,
    GraspTimeline,
    GripperRig,
    select_frames,
    selection_window,
    simulate_timeline,
)

__all__ = ["GraspSample", "SimulationOptions", "make_context", "render_recording", "simulate_grasp"]


@dataclass(frozen=True)
class SimulationOptions:
    """Numerical options of the generator (physics parameters live in their modules).

    Attributes:
        image_size: stored image size (H, W) [px]; the field of view is always the
            real crop (30.6 x 21.9 mm), so smaller images have larger pixels.
        curve_cell_mm: pad-grid spacing of the force-approach curves [mm].
        render_cell_mm: pad-grid spacing of the gel fields that are rendered [mm].
        estimator_scale: resolution of the estimator/selection sequence relative to
            250 x 350 [-].
        n_sessions: number of recording sessions (sensor set-ups) objects are spread over.
        max_aug: maximum number of time-shift augmentations.
        depth_solve_scale: resolution of the Poisson solve of the stored depth maps
            relative to the image [-] (see ``depth.reconstruct_depth``).
        rig: the gripper and its controller (peak force, finger stiffness); the one
            physical parameter set here, because it belongs to the set-up, not the object.
    """

    image_size: tuple[int, int] = FULL_SIZE
    curve_cell_mm: float = 0.5
    render_cell_mm: float = 0.25
    estimator_scale: float = 0.25
    n_sessions: int = 16
    max_aug: int = 5
    depth_solve_scale: float = 0.5
    rig: GripperRig = DATASET_RIG

    @property
    def estimator_size(self) -> tuple[int, int]:
        """Image size of the estimator sequence (H, W) [px]."""
        return (
            max(round(FULL_SIZE[0] * self.estimator_scale), 16),
            max(round(FULL_SIZE[1] * self.estimator_scale), 16),
        )


@dataclass
class Session:
    """Sensor set-up of one recording session: per finger gel and appearance."""

    gels: tuple[GelModel, GelModel]
    looks: tuple[SensorLook, SensorLook]
    finger_stiffness_n_per_m: float


@lru_cache(maxsize=64)
def _session(seed: int, session_id: int, rig: GripperRig) -> Session:
    rng = stream(seed, "session", session_id)
    gels = tuple(
        GelModel(
            modulus_pa=rig.gel_modulus_pa * 10 ** rng.normal(0.0, rig.gel_modulus_sd_decades),
            thickness_mm=float(rng.uniform(*rig.gel_thickness_mm)),
        )
        for _ in range(2)
    )
    randomised = {
        "light_jitter": rig.light_jitter,
        "read_noise_grey": rig.read_noise_grey,
        "background_jitter": rig.background_jitter,
    }
    looks = (
        sample_sensor_look(rng, markers=False, **randomised),
        sample_sensor_look(rng, markers=True, **randomised),
    )
    # Scales the drawn strengths, drawing nothing: a rig's balance changes no other draw.
    looks = tuple(  # type: ignore[assignment]
        replace(look, light_gain=tuple(np.multiply(look.light_gain, rig.light_balance).tolist()))
        for look in looks
    )
    stiffness = rig.draw_finger_stiffness_n_per_m(rng)
    if rig.edge_glow_grey_per_mm[1] > 0:
        # Drawn last, so rigs without a glow keep every earlier draw (and their data).
        looks = tuple(  # type: ignore[assignment]
            replace(look, edge_glow=sample_edge_glow(rng, rig.edge_glow_grey_per_mm))
            for look in looks
        )
    return Session(gels, looks, stiffness)  # type: ignore[arg-type]


@dataclass
class ObjectContext:
    """Everything fixed for an object's grasps (built once per object)."""

    spec: ObjectSpec
    seed: int
    options: SimulationOptions
    session: Session
    textures: tuple[np.ndarray, np.ndarray] = field(repr=False)


def make_context(spec: ObjectSpec, seed: int, options: SimulationOptions) -> ObjectContext:
    """Session assignment and texture canvases of an object."""
    sid = int(stream(seed, spec.name, "session").integers(0, max(options.n_sessions, 1)))
    session = _session(seed, sid, options.rig)
    size = render_size(options.image_size)  # textures are cut at the rendered size
    px = pixel_size_mm(size)
    tex_rng = stream(seed, spec.name, "texture-canvas")
    textures = (
        texture_canvas(spec.texture, size, px, tex_rng),
        texture_canvas(spec.texture, size, px, tex_rng),
    )
    return ObjectContext(spec, seed, options, session, textures)


@dataclass
class GraspSample:
    """One ``grasp=g/augmentation=k`` directory.

    Attributes:
        rgb, rgb_markers: difference images (3, H, W, 3), BGR, float32.
        depth, depth_markers: reconstructed depth (3, H, W) [mm], float32.
        forces: measured force at the three frames [N].
        widths: measured gripper width at the three frames [m].
        elastic_estimate: Hooke estimate [Pa] (NaN if not estimable).
        hertz_estimate: Hertz/MDR estimate of E* [Pa] (NaN if not estimable).
        rig_estimates: the same pair [Pa] with the rig's own closure taken out at the
            rig's nominal stiffness (``GripperRig.stiffness_n_per_m``), as ``record --rig``
            makes them on a real rig; NaN where not estimable.
    """

    rgb: np.ndarray
    depth: np.ndarray
    rgb_markers: np.ndarray
    depth_markers: np.ndarray
    forces: np.ndarray
    widths: np.ndarray
    elastic_estimate: float
    hertz_estimate: float
    rig_estimates: tuple[float, float] = (math.nan, math.nan)


@dataclass
class GraspResult:
    """A simulated grasp: its samples (empty if the selection skipped it) and internals."""

    samples: list[GraspSample]
    timeline: GraspTimeline
    selection: AugmentedSelection | None
    reference_approach_mm: tuple[float, float] = (0.0, 0.0)


def _object_mechanics(spec: ObjectSpec) -> ObjectMechanics:
    size = spec.geometry.thickness_mm
    if spec.hollow:
        # A thin wall is all the material there is to compress.
        size = min(size, 4.0 * spec.shell_thickness_mm)
    return ObjectMechanics(
        modulus_pa=spec.physics_modulus_pa,
        poisson=spec.poisson,
        size_mm=size,
        max_strain=spec.max_strain,
        shell_stiffness_n_per_m=spec.shell_stiffness_n_per_m,
    )


def _render_sequence(
    approaches_mm: np.ndarray,
    sag: np.ndarray,
    grid: PadGrid,
    gel: GelModel,
    obj: ObjectMechanics,
    look: SensorLook,
    size: tuple[int, int],
    rng: np.random.Generator,
    texture: np.ndarray | None = None,
    texture_share: float = 1.0,
    solve_scale: float = 1.0,
    jpeg: bool = True,
    rig: GripperRig = DATASET_RIG,
    reference_approach_mm: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Difference images (n, H, W, 3) and reconstructed depth (n, H, W) for approaches;
    ``rig``'s soft contact (``soft_contact_spread``, ``soft_edge_glow``) shapes compliant
    imprints and their glow. A positive ``reference_approach_mm`` [mm] takes the
    reference frame in that light contact (a recording that starts touching)."""
    approaches = np.asarray(approaches_mm, dtype=np.float64)
    touching_reference = reference_approach_mm > 0
    if touching_reference:
        approaches = np.append(approaches, reference_approach_mm)
    fields, shares = gel_compression(
        sag, gel, obj, grid, approaches, spread=rig.soft_contact_spread
    )
    height, contact = gel_height_maps(fields, grid, size, gel.thickness_mm)
    if texture is not None:
        height += np.float32(texture_share) * texture[None] * contact
        np.maximum(height, 0.0, out=height)
    if not jpeg and look.jpeg_quality:
        look = replace(look, jpeg_quality=0)
    glow = 1.0 + rig.soft_edge_glow * shares if rig.soft_edge_glow else None
    if touching_reference:
        reference = render_frames(
            height[-1:], look, rng, glow_scale=None if glow is None else glow[-1:]
        )[0]
        height, glow = height[:-1], None if glow is None else glow[:-1]
    else:
        reference = reference_frame(look, size, rng)
    frames = render_frames(height, look, rng, glow_scale=glow)
    diff = difference_images(frames, reference)
    depth = reconstruct_depth(diff, markers=look.markers, solve_scale=solve_scale)
    return diff, depth


@lru_cache(maxsize=8)
def _estimator_constants(width_px: int) -> DatasetEstimatorConstants:
    """The dataset estimator's constants for depth maps ``width_px`` wide.

    The estimator assumes its own pixel pitch (16.40 px/mm) on 350-px-wide frames; on a
    coarser grid the same quirk is kept at the same scale, and the 10 x 10 px Hertz patch
    shrinks with the grid (at least 2 x 2 px).
    """
    factor = width_px / FULL_SIZE[1]
    return replace(
        DATASET_CONSTANTS,
        px_per_mm=DATASET_CONSTANTS.px_per_mm * factor,
        patch_radius_px=max(round(DATASET_CONSTANTS.patch_radius_px * factor), 1),
    )


def _estimates(
    timeline: GraspTimeline,
    depth_mm: np.ndarray,
    max_depth_mm: np.ndarray,
    frames: np.ndarray,
    width_px: int,
    rig_stiffness_n_per_m: float | None = None,
) -> tuple[float, float]:
    """Both analytical estimates as the dataset's code made them (``DEFAULT_ESTIMATOR``),
    rig-corrected at ``rig_stiffness_n_per_m`` [N/m] when given.

    ``depth_mm`` holds the force-sensing finger's depth maps of the consecutive
    ``frames``; ``max_depth_mm`` (2, T) both fingers' maximum depth per frame of the
    whole recording. The published driver loads the whole recording and clips it to the
    press by force, then to the first frame where either finger's depth reaches 7.5 % of
    its peak (``dataset_press_window``); only the frames of ``frames`` (which cover the
    press) are rendered, so the clip is taken on the whole series and the fits on it.
    """
    start, end = dataset_press_window(timeline.force_n, max_depth_mm[0], max_depth_mm[1])
    if start < frames[0] or end > frames[-1] + 1:
        return math.nan, math.nan  # no press: the original fitted the whole recording
    try:
        elastic, hertz = dataset_estimates_pa(
            timeline.force_n[start:end],
            interpolate_repeated_widths(timeline.width_m[start:end]),
            depth_mm[start - frames[0] : end - frames[0]],
            _estimator_constants(width_px),
            preprocess=False,
            rig_stiffness_n_per_m=rig_stiffness_n_per_m,
        )
    except ValueError:
        return math.nan, math.nan
    return float(elastic), float(hertz)


def _grasp_key(ctx: ObjectContext, grasp: int) -> tuple[object, ...]:
    """The random-stream key of a grasp: (seed, object, "grasp", number)."""
    return (ctx.seed, ctx.spec.name, "grasp", int(grasp))


def _poses(ctx: ObjectContext, grasp: int) -> tuple[np.random.Generator, tuple[object, object]]:
    """The pose stream of a grasp and the object's pose on each finger (mirrored)."""
    kind = ctx.spec.geometry.kind
    pose_rng = stream(*_grasp_key(ctx, grasp), "pose")
    first = sample_pose(pose_rng, kind)
    return pose_rng, (first, sample_pose(pose_rng, kind, mirror_of=first))


def _render_full_size(
    ctx: ObjectContext,
    grasp: int,
    finger: int,
    approaches_mm: np.ndarray,
    render_sag: np.ndarray,
    obj: ObjectMechanics,
    texture_rng: np.random.Generator,
    reference_approach_mm: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Full-size difference images and depth of one finger for the given approaches (the
    reference frame at ``reference_approach_mm`` [mm], 0: no contact)."""
    opt, gels = ctx.options, ctx.session.gels
    # How much of the object's texture shows through depends on its stiffness vs the gel.
    gel_share = obj.plane_strain_modulus_pa / (
        obj.plane_strain_modulus_pa + gels[0].plane_strain_modulus_pa
    )
    size = render_size(opt.image_size)
    diff, depth = _render_sequence(
        approaches_mm,
        render_sag,
        PadGrid(opt.render_cell_mm),
        gels[finger],
        obj,
        ctx.session.looks[finger],
        size,
        stream(*_grasp_key(ctx, grasp), "render-full", finger),
        texture=texture_window(ctx.textures[finger], size, texture_rng),
        texture_share=gel_share,
        solve_scale=opt.depth_solve_scale,
        rig=opt.rig,
        reference_approach_mm=reference_approach_mm,
    )
    return to_stored_size(diff, opt.image_size), to_stored_size(depth, opt.image_size)


def _reference_approaches(
    ctx: ObjectContext, grasp: int, curves: tuple[ContactCurve, ...]
) -> tuple[float, float]:
    """Each finger's approach [mm] when its reference frame is taken: 0 (no contact), or,
    with the rig's ``reference_contact_probability``, at a light force drawn from
    ``reference_contact_n`` (its own stream: a rig without it draws nothing)."""
    rig = ctx.options.rig
    if rig.reference_contact_probability <= 0:
        return (0.0, 0.0)
    rng = stream(*_grasp_key(ctx, grasp), "reference-contact")
    if rng.random() >= rig.reference_contact_probability:
        return (0.0, 0.0)
    force_n = float(rng.uniform(*rig.reference_contact_n))
    return tuple(float(c.approach_at(force_n)) for c in curves)  # type: ignore[return-value]


def simulate_grasp(ctx: ObjectContext, grasp: int) -> GraspResult:
    """Simulate grasp ``grasp`` of an object (deterministic for (seed, object, grasp))."""
    spec, opt = ctx.spec, ctx.options
    key = _grasp_key(ctx, grasp)
    pose_rng, poses = _poses(ctx, grasp)
    curve_grid, render_grid = PadGrid(opt.curve_cell_mm), PadGrid(opt.render_cell_mm)
    obj = _object_mechanics(spec)
    gels = ctx.session.gels
    curves = tuple(
        force_curve(sag_map(spec.geometry, curve_grid, poses[f], side=f), gels[f], obj, curve_grid)
        for f in range(2)
    )
    # Where along the finger the object sits changes the lever: +-25 % per grasp.
    stiffness = ctx.session.finger_stiffness_n_per_m * 10 ** pose_rng.normal(0.0, 0.1)
    timeline = simulate_timeline(
        curves,  # type: ignore[arg-type]
        spec.geometry.thickness_mm * 1e-3,
        stiffness,
        spec.shell_stiffness_n_per_m,
        stream(*key, "timeline"),
        # A sphere cannot rotate into a more stable pose.
        settle_probability=0.1 if spec.geometry.kind == "Sphere" else 0.35,
        peak_force_n=opt.rig.peak_force_n,
        force_baseline_sd_n=opt.rig.force_baseline_sd_n,
    )
    reference_mm = _reference_approaches(ctx, grasp, curves)
    window = selection_window(timeline.force_n, opt.max_aug)
    if window is None:
        return GraspResult([], timeline, None, reference_mm)  # peak force < 10 N or too few frames
    press = dataset_force_press(timeline.force_n)
    lo, hi = window[0], window[2]
    if press is not None:
        lo, hi = min(lo, press[0]), max(hi, press[1])
    seq_frames = np.arange(lo, hi)
    render_sags = [sag_map(spec.geometry, render_grid, poses[f], side=f) for f in range(2)]
    est_size = opt.estimator_size
    seq = []
    max_depth = np.zeros((2, timeline.force_n.size))
    for f in range(2):
        _, depth = _render_sequence(
            timeline.approach_mm[f, seq_frames],
            render_sags[f],
            render_grid,
            gels[f],
            obj,
            ctx.session.looks[f],
            est_size,
            stream(*key, "render-sequence", f),
            # JPEG blocks are below this resolution; skipping the codec saves time.
            jpeg=False,
            rig=opt.rig,
            reference_approach_mm=reference_mm[f],
        )
        seq.append(depth)
        max_depth[f, seq_frames] = depth.reshape(seq_frames.size, -1).max(axis=1)
    selection = select_frames(
        timeline.force_n, max_depth[0], max_depth[1], spec.modulus_pa, max_aug=opt.max_aug
    )
    if selection is None:
        return GraspResult([], timeline, None, reference_mm)
    elastic, hertz = _estimates(timeline, seq[0], max_depth, seq_frames, est_size[1])
    rig_estimates = _estimates(
        timeline, seq[0], max_depth, seq_frames, est_size[1], opt.rig.stiffness_n_per_m
    )

    # Full resolution, stored frames only.
    tex_rng = stream(*key, "texture")
    rendered = []
    for f, video in enumerate(selection.fingers):
        idx = np.unique((video[:, None] + np.arange(selection.num_aug)).ravel())
        diff, depth = _render_full_size(
            ctx,
            grasp,
            f,
            timeline.approach_mm[f, idx],
            render_sags[f],
            obj,
            tex_rng,
            reference_mm[f],
        )
        rendered.append((idx, diff, depth))
    samples = []
    for k in range(selection.num_aug):
        parts = []
        for f, video in enumerate(selection.fingers):
            idx, diff, depth = rendered[f]
            pos = np.searchsorted(idx, video + k)
            parts.append((diff[pos], depth[pos]))
        fi = selection.force + k
        samples.append(
            GraspSample(
                rgb=parts[0][0],
                depth=parts[0][1],
                rgb_markers=parts[1][0],
                depth_markers=parts[1][1],
                forces=timeline.force_n[fi].astype(np.float64),
                widths=timeline.width_m[fi].astype(np.float64),
                elastic_estimate=elastic,
                hertz_estimate=hertz,
                rig_estimates=rig_estimates,
            )
        )
    return GraspResult(samples, timeline, selection, reference_mm)


def camera_times_s(timeline_times_s: np.ndarray, fps: float) -> np.ndarray:
    """Frame times (s) of a camera at a constant ``fps`` (1/s) over a time line's span,
    starting at its first frame."""
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be a positive frame rate (1/s), got {fps!r}")
    start, end = float(timeline_times_s[0]), float(timeline_times_s[-1])
    return start + np.arange(int((end - start) * fps) + 1) / fps


def render_recording(
    ctx: ObjectContext, grasp: int, finger: int = 0, *, fps: float | None = None
) -> tuple[GraspResult, np.ndarray]:
    """A grasp and every frame of one finger's recording at full size.

    Returns the simulated grasp (as :func:`simulate_grasp`) and difference images
    (T, H, W, 3), BGR, for all T frames of its time line: the same pose, sensor and
    texture window as the stored frames, and noise from the same stream (so a stored
    frame and the same frame here differ only by read noise). For streaming studies.

    ``fps``: render as a camera at this constant rate (1/s) would see the grasp instead,
    at :func:`camera_times_s` over the time line's span: the gel's approach is
    interpolated linearly between the time line's frames (30 fps), so every frame rate
    sees the same press.
    """
    if finger not in (0, 1):
        raise ValueError(f"finger must be 0 (markerless) or 1 (markers), got {finger}")
    result = simulate_grasp(ctx, grasp)
    approach = result.timeline.approach_mm[finger]
    if fps is not None:
        times = result.timeline.times_s
        approach = np.interp(camera_times_s(times, fps), times, approach)
    _, poses = _poses(ctx, grasp)
    texture_rng = stream(*_grasp_key(ctx, grasp), "texture")
    if finger == 1:  # the stored frames draw finger 0's texture window first
        texture_window(ctx.textures[0], render_size(ctx.options.image_size), texture_rng)
    render_sag = sag_map(
        ctx.spec.geometry, PadGrid(ctx.options.render_cell_mm), poses[finger], side=finger
    )
    diff, _ = _render_full_size(
        ctx,
        grasp,
        finger,
        approach,
        render_sag,
        _object_mechanics(ctx.spec),
        texture_rng,
        result.reference_approach_mm[finger],
    )
    return result, diff
