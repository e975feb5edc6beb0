"""The generator held against the real Wedge rig: how far the gripper closes at each force.

Reads the readings of the real grasps in ``../shared/reference-data/real/wedge-grasps/``
(``timestamp_s,force_n,width_m`` per frame) and simulates the same five objects with their
rows of the real object table (E, shape, material; the elastic balls' 25 mm radius, the
golf ball's 21.3 mm), three grasps each, with the generator as `simulate --object-table`
runs it. For every grasp it prints:

* ``F_peak``: the peak force [N];
* ``contact W``: the width [mm] at contact (the first frame 1 N above the no-contact level
  of ``data.force_readings.force_baseline``, so an unzeroed baseline does not count);
* ``close@10N`` and ``close@peak``: how far the width closed [mm] from contact to the first
  frame at 10 N above the baseline, and to the peak;
* ``k``: the apparent stiffness [N/mm] of the rig and the object in series, the slope of a
  line through (closure, force) between 2 N and 90 % of the peak.

For the golf ball (850 MPa) the object barely deforms, so its closure is the rig's own:
gel, fingers, mount and the width reading.

With ``--real-store`` (the store ``benchmarks/real_grasps.py`` writes to ``OUT/work/store``)
it also compares the difference images the models see: the third frame of each grasp's
first augmentation, real against the same five objects simulated at 250 x 350 px with the
same rig. Per object: the share of the frame in contact (any channel more than 15 grey
levels from the reference), the 99th percentile of |difference| per channel (R, G, B;
0.5 = 128 grey levels), the median |difference| outside the contact (noise and
drift), the green edge's glow (:func:`edge_glow_grey`), the 99th percentile of the
largest channel's |difference| beyond the left 15 % of the frame (the imprint without the
glow), the stored depth map's peak [mm]
and the contact share at each of the three selected frames against their force (contact
area against force). It then reads every frame of every grasp, the real videos through
the calibrations ``benchmarks/real_grasps.py`` made (``OUT/work/calibrations``) and the
generator's rendered frames, and prints the contact share and the depth map's peak (the
dataset's heuristic on both sides) at 5, 10, 15 and 20 N (``--contact-figure`` and
``--depth-figure`` draw the curves). ``--gel-mechanics`` prints the generator's contact
mechanics alone: a rigid golf ball's geometric contact area on gel variants.

    python benchmarks/real_vs_synthetic.py              # ~10 s
    python benchmarks/real_vs_synthetic.py --rig wedge-2023 --json out.json
    python benchmarks/real_vs_synthetic.py --rig wedge-2023 --real-store real-out/work/store
    # one point of the gel fit: the golf ball on a gel of 8.5e4 Pa
    python benchmarks/real_vs_synthetic.py --rig wedge-2023 --real-store real-out/work/store \
        --objects golf_ball --gel-pa 8.5e4 --finger-stiffness 3.0e3,4.0e3 --glow-gain 1150,4600
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import tempfile
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from tactile_compliance.data.force_readings import force_baseline

if TYPE_CHECKING:
    from tactile_compliance.synthetic.timeseries import GripperRig

REFERENCE = Path(__file__).resolve().parents[2] / "shared/reference-data"
OBJECTS = {  # file prefix -> (label in the object table, radius [m] or None)
    "foam_brick": ("foam_brick", None),
    "golf_ball": ("golf_ball", 0.0213),
    "green_ball_softer": ("green_elastic_ball", 0.025),
    "orange_ball_softest": ("orange_elastic_ball", 0.025),
    "purple_ball_hardest": ("purple_elastic_ball", 0.025),
}


def closure_stats(force_n: np.ndarray, width_m: np.ndarray) -> dict[str, float]:
    """Peak force, contact width and closures of one grasp (see the module docstring)."""
    base = force_baseline(force_n).level_n  # the rule `record` reports baselines with
    above = force_n - base
    contact = int(np.flatnonzero(above >= 1.0)[0])
    peak = int(np.argmax(force_n))
    at10 = np.flatnonzero(above >= 10.0)
    closure_mm = (width_m[contact] - width_m) * 1e3
    window = np.arange(contact, peak + 1)
    window = window[(above[window] >= 2.0) & (above[window] <= 0.9 * above[peak])]
    slope = (
        float(np.polyfit(closure_mm[window], above[window], 1)[0]) if window.size > 2 else np.nan
    )
    return {
        "F_peak_n": float(force_n[peak]),
        "contact_width_mm": float(width_m[contact] * 1e3),
        "closure_10n_mm": float(closure_mm[at10[0]]) if at10.size else float("nan"),
        "closure_peak_mm": float(closure_mm[peak]),
        "stiffness_n_per_mm": slope,
        "curve_closure_mm": closure_mm[contact : peak + 1].round(3).tolist(),
        "curve_force_n": above[contact : peak + 1].round(3).tolist(),
    }


def real_grasps(folder: Path) -> dict[str, list[dict[str, float]]]:
    out: dict[str, list[dict[str, float]]] = {}
    for prefix, (label, _) in OBJECTS.items():
        for path in sorted(folder.glob(f"{prefix}_[0-9]_readings.csv")):
            data = np.loadtxt(path, delimiter=",", skiprows=1)
            out.setdefault(label, []).append(closure_stats(data[:, 1], data[:, 2]))
    return out


def write_five_table(table: Path, path: Path, labels: list[str] | None = None) -> Path:
    """The five objects' rows of the real object table (or those of ``labels``), with the
    balls' known radii."""
    with open(table, newline="", encoding="utf-8") as handle:
        rows = list(csv.DictReader(handle))
    radius = {label: r for label, r in OBJECTS.values() if labels is None or label in labels}
    chosen = [dict(r) for r in rows if r["Label"] in radius]
    for row in chosen:
        if radius[row["Label"]] is not None:
            row["Radius [m]"] = str(radius[row["Label"]])
    with open(path, "w", newline="", encoding="utf-8") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(chosen[0]))
        writer.writeheader()
        writer.writerows(chosen)
    return path


def simulated_recordings(
    table: Path, seed: int, rig: GripperRig, labels: list[str] | None, image_size: tuple[int, int]
) -> Iterator[tuple[str, Any, np.ndarray]]:
    """``(label, simulated grasp, every frame)`` for the five objects' 3 grasps each, as
    `simulate --object-table` makes them, rendered at ``image_size`` (H, W) [px]."""
    from tactile_compliance.synthetic.grasp import SimulationOptions, make_context, render_recording
    from tactile_compliance.synthetic.objects import objects_from_table

    with tempfile.TemporaryDirectory() as tmp:
        path = write_five_table(table, Path(tmp) / "five.csv", labels)
        specs, _ = objects_from_table(path, seed=seed, grasps_per_object=3)
    for spec in specs:
        ctx = make_context(spec, seed, SimulationOptions(image_size=image_size, rig=rig))
        for grasp in range(spec.n_grasps):
            result, frames = render_recording(ctx, grasp)
            yield spec.name, result, frames


def simulated_grasps(
    table: Path, seed: int, rig: GripperRig, labels: list[str] | None = None
) -> dict[str, list[dict[str, float]]]:
    out: dict[str, list[dict[str, float]]] = {}
    # A small size: only the force and width time lines are used.
    for label, result, _ in simulated_recordings(table, seed, rig, labels, (125, 175)):
        timeline = result.timeline
        out.setdefault(label, []).append(
            closure_stats(np.asarray(timeline.force_n), np.asarray(timeline.width_m))
        )
    return out


#: A pixel is in contact where some channel differs from the reference by more than this
#: many grey levels.
CONTACT_GREY = 15


def contact_mask(diff: np.ndarray) -> np.ndarray:
    """Where frames (..., H, W, 3; difference around 0) are in contact (CONTACT_GREY)."""
    return np.abs(diff).max(axis=-1) > CONTACT_GREY / 255


def contact_share(diff: np.ndarray) -> np.ndarray:
    """Share of each frame (..., H, W, 3; difference around 0) in contact."""
    return contact_mask(diff).mean(axis=(-2, -1))


def image_stats(store_path: Path) -> dict[str, dict[str, float]]:
    """Difference-image statistics per object (see the module docstring)."""
    from tactile_compliance.data.store import GraspStore

    store = GraspStore.open(store_path)
    samples = store.samples
    chosen = samples[(samples.augmentation == 0) & (samples.finger == "markerless")]
    out = {}
    for label, rows in chosen.groupby("object"):
        frames = store.load_frames(rows.sample_id.to_numpy()) - 0.5  # (n, 3, H, W, RGB)
        diff = frames[:, 2]
        contact = contact_mask(diff)  # (n, H, W)
        shares = contact_share(frames)  # (n, 3)
        out[str(label)] = {
            "contact_share": float(contact.mean()),
            # Contact area against force over the three selected frames.
            "contact_share_by_frame": shares.mean(axis=0).round(4).tolist(),
            "force_by_frame_n": [float(rows[f"force_n_{i}"].mean()) for i in range(3)],
            # The stored depth map's peak [mm] (record: the sensor's depth model).
            "depth_max_mm": float(rows["depth_max_mm_2"].mean()),
            # The stored analytical estimates (geometric means) [Pa]: an ALL model's input.
            **{
                f"{name}_pa": float(10 ** np.log10(rows[f"{name}_estimate_pa"]).mean())
                for name in ("elastic", "hertz")
            },
            **{
                f"p99_{c}": float(np.mean(np.percentile(np.abs(diff[..., i]), 99, axis=(1, 2))))
                for i, c in enumerate("RGB")
            },
            "edge_glow_grey": edge_glow_grey(diff),
            # The imprint itself: away from the left edge's glow (beyond 15 % of W).
            "p99_away_from_edge": float(
                np.mean(
                    np.percentile(
                        np.abs(diff[:, :, round(0.15 * diff.shape[2]) :]).max(axis=-1),
                        99,
                        axis=(1, 2),
                    )
                )
            ),
            "outside_median": float(np.median(np.abs(diff).max(axis=-1)[~contact])),
        }
    return out


def edge_glow_grey(diff: np.ndarray) -> float:
    """The green edge's glow (``synthetic.render``) in difference images (n, H, W, RGB):
    the mean of G - R over the left 6 % of the columns, less its mean beyond 11 % (the
    contact's own colour) [grey levels]."""
    width = diff.shape[2]
    g_minus_r = (diff[..., 1] - diff[..., 0]) * 255.0
    left = g_minus_r[:, :, : round(0.06 * width)].mean()
    rest = g_minus_r[:, :, round(0.11 * width) :].mean()
    return float(left - rest)


def background_stats(frame_bgr: np.ndarray) -> dict[str, object]:
    """A no-contact frame (H, W, 3) uint8 BGR: per channel (R, G, B) the mean, the
    vignetting (centre fifth less the four corner tenths) and the fine noise (standard
    deviation after a 9 x 9 box blur is removed) [grey levels], and the column and row
    profiles (means)."""
    import cv2

    rgb = frame_bgr[..., ::-1].astype(np.float32)
    h, w = rgb.shape[:2]
    centre = rgb[2 * h // 5 : 3 * h // 5, 2 * w // 5 : 3 * w // 5].mean(axis=(0, 1))
    ch, cw = h // 10, w // 10
    corners = np.mean(
        [rgb[:ch, :cw], rgb[:ch, -cw:], rgb[-ch:, :cw], rgb[-ch:, -cw:]], axis=(0, 1, 2)
    )
    fine = rgb - cv2.blur(rgb, (9, 9))
    return {
        "mean": rgb.mean(axis=(0, 1)).round(1).tolist(),
        "vignetting": (centre - corners).round(1).tolist(),
        "fine_noise": fine[5:-5, 5:-5].std(axis=(0, 1)).round(2).tolist(),
        "columns": rgb.mean(axis=0).T.round(1).tolist(),
        "rows": rgb.mean(axis=1).T.round(1).tolist(),
    }


def backgrounds(real_frame: Path, seed: int, looks: int) -> dict[str, list[dict[str, object]]]:
    """The real warped no-contact frame, cropped 25 px per side as the dataset was, and
    the no-contact frames of ``looks`` sensor appearances drawn as the generator draws
    one per recording session (``render.sample_sensor_look``), at the same size."""
    import cv2

    from tactile_compliance.synthetic.render import reference_frame, sample_sensor_look
    from tactile_compliance.synthetic.rng import stream

    frame = cv2.imread(str(real_frame), cv2.IMREAD_COLOR)
    if frame is None:
        raise SystemExit(f"cannot read {real_frame}")
    real = frame[25:-25, 25:-25]
    generated = [
        reference_frame(
            sample_sensor_look(stream(seed, "session", k), markers=False),
            real.shape[:2],
            stream(seed, "noise", k),
        )
        for k in range(looks)
    ]
    return {
        "real": [background_stats(real)],
        "generator": [background_stats(g) for g in generated],
    }


def print_backgrounds(results: dict[str, list[dict[str, object]]]) -> None:
    print("\nno-contact frame     mean R/G/B            vignetting R/G/B      fine noise R/G/B")
    for source, rows in results.items():
        for row in rows:
            print(
                f"{source:20s} "
                + "  ".join(
                    " ".join(f"{v:5.1f}" for v in row[key])  # type: ignore[union-attr]
                    for key in ("mean", "vignetting", "fine_noise")
                )
            )


def draw_backgrounds(results: dict[str, list[dict[str, object]]], path: Path) -> None:
    """Column and row profiles of the no-contact frames, real against generated."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 3.4))
    for ax, key, xlabel in ((axes[0], "columns", "column [px]"), (axes[1], "rows", "row [px]")):
        for source, style, width in (("generator", "--", 0.8), ("real", "-", 2.0)):
            for k, row in enumerate(results[source]):
                for c, colour in enumerate(("red", "green", "blue")):
                    ax.plot(
                        row[key][c],  # type: ignore[index]
                        style,
                        color=colour,
                        lw=width,
                        alpha=1.0 if source == "real" else 0.5,
                        label=f"{source}" if (k == 0 and c == 1) else None,
                    )
        ax.set_xlabel(xlabel)
        ax.set_ylabel("mean grey level")
    axes[0].set_title("across the frame (left to right)", fontsize=9)
    axes[1].set_title("down the frame (top to bottom)", fontsize=9)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=80)


#: Forces above the no-contact level [N] at which the contact curves are read.
CURVE_FORCES_N = (5.0, 10.0, 15.0, 20.0)


def at_forces(force_above_n: np.ndarray, values: np.ndarray) -> list[float]:
    """Per-frame ``values`` at :data:`CURVE_FORCES_N`, from the loading part of one grasp
    (up to its force peak; NaN for a force it never reaches)."""
    peak = int(np.argmax(force_above_n))
    rising = np.maximum.accumulate(force_above_n[: peak + 1])  # monotone for np.interp
    return [
        float(np.interp(f, rising, values[: peak + 1])) if f <= rising[-1] else float("nan")
        for f in CURVE_FORCES_N
    ]


#: The outer edge of a contact: where the largest channel's |difference|, blurred over
#: OUTER_BLUR_PX, exceeds this many grey levels. Blurred and low, it takes in a textured
#: contact whole, however faint its texture's contrast (the golf ball's dimples).
OUTER_GREY = 8
OUTER_BLUR_PX = 6.0
#: Left share of the frame left out of the outer edge: the Wedge's green edge glow.
GLOW_STRIP = 0.15


def outer_radius_mm(diff: np.ndarray) -> float:
    """Equivalent radius [mm] of the largest region inside :data:`OUTER_GREY`, holes filled,
    away from the glow strip, in one difference image (H, W, 3; 0.5 = no change); NaN
    without one."""
    from tactile_compliance.data.depth_model import largest_region
    from tactile_compliance.synthetic.render import VISIBLE_SIZE_MM

    grey = np.abs(np.asarray(diff, dtype=np.float32) - 0.5).max(axis=-1) * 255
    grey = cv2.GaussianBlur(grey, (0, 0), OUTER_BLUR_PX)
    grey[:, : int(GLOW_STRIP * grey.shape[1])] = 0
    outline = largest_region(grey > OUTER_GREY)
    if outline is None:
        return float("nan")
    filled = cv2.drawContours(np.zeros(grey.shape, np.uint8), [outline], -1, 1, thickness=-1)
    mm_per_px = VISIBLE_SIZE_MM[0] / grey.shape[1]
    return float(np.sqrt(filled.sum() / np.pi) * mm_per_px)


def real_contact_curves(folder: Path, calibrations: Path) -> dict[str, list[dict[str, list]]]:
    """Contact share against force over every frame of every real grasp, through the
    calibrations ``benchmarks/real_grasps.py`` made (``OUT/work/calibrations``)."""
    from tactile_compliance.acquisition.calibration import SensorCalibration
    from tactile_compliance.acquisition.sensors import iter_frames
    from tactile_compliance.data.store import frames_from_uint8
    from tactile_compliance.inference.streaming import difference_image

    out: dict[str, list[dict[str, list]]] = {}
    for prefix, (label, _) in OBJECTS.items():
        for video in sorted(folder.glob(f"{prefix}_[0-9].avi")):
            calibration = SensorCalibration.load(calibrations / f"{video.stem}.json")
            with calibration.open(f"wedge:{video}") as source:
                diffs = [
                    difference_image(frame, calibration.reference)
                    for _, frame in iter_frames(source)
                ]
            diff = frames_from_uint8(np.stack(diffs))
            force = np.loadtxt(
                video.with_name(f"{video.stem}_readings.csv"), delimiter=",", skiprows=1
            )[: len(diff), 1]
            out.setdefault(label, []).append(_curve(force, diff))
    return out


def simulated_contact_curves(
    table: Path, seed: int, rig: GripperRig, labels: list[str] | None = None
) -> dict[str, list[dict[str, list]]]:
    """The same for the five objects simulated at 250 x 350 px (every frame rendered)."""
    out: dict[str, list[dict[str, list]]] = {}
    for label, result, frames in simulated_recordings(table, seed, rig, labels, (250, 350)):
        out.setdefault(label, []).append(_curve(result.timeline.force_n, frames))
    return out


#: What the curves read from every frame: its contact share (:data:`CONTACT_GREY`), the
#: contact's outer radius (:func:`outer_radius_mm`) and the peak of its depth map [mm] by
#: the dataset's heuristic, as ``record`` computes it without a depth calibration (on both
#: sides; the Wedge grasps come with no ball presses).
CURVE_SERIES = {
    "contact_share": "contact share of the frame",
    "outer_radius_mm": "contact's outer radius [mm]",
    "depth_peak_mm": "depth peak [mm]",
}


def _curve(force_n: np.ndarray, diff: np.ndarray) -> dict[str, list]:
    """One grasp's curves from its force [N] and difference images (T, H, W, 3; BGR in
    [0, 1], 0.5 = no change); ``frames_at_forces`` keeps the frames nearest
    :data:`CURVE_FORCES_N` (uint8, for :func:`draw_frames`; not written to JSON)."""
    from tactile_compliance.data.photometric import reconstruct_depth

    above = np.asarray(force_n, dtype=np.float64) - force_baseline(force_n).level_n
    series = {
        "contact_share": contact_share(diff.astype(np.float32) - 0.5),
        "outer_radius_mm": [outer_radius_mm(frame) for frame in diff],
        "depth_peak_mm": reconstruct_depth(diff).max(axis=(1, 2)),
    }
    curve: dict[str, Any] = {"force_above_n": above.round(3).tolist()}
    for key, values in series.items():
        curve[key] = np.asarray(values).round(4).tolist()
        curve[f"{key}_at_forces"] = at_forces(above, np.asarray(values))
    nearest = at_forces(above, np.arange(len(above), dtype=np.float64))
    curve["frames_at_forces"] = [
        None if np.isnan(i) else np.uint8(np.clip(diff[round(i)], 0, 1) * 255) for i in nearest
    ]
    return curve


def print_contact_curves(curves: dict[str, dict[str, list]]) -> None:
    forces = "  ".join(f"{f:5.0f} N" for f in CURVE_FORCES_N)
    for key, name in CURVE_SERIES.items():
        print(
            f"\n{name} against force (every frame, mean of the grasps)\n{'object':21s} "
            f"{'source':9s}  {forces}"
        )
        for label, _ in OBJECTS.values():
            for source in ("real", "generator"):
                grasps = curves[source].get(label)
                if grasps:
                    with warnings.catch_warnings():  # NaN where no grasp has a value
                        warnings.simplefilter("ignore", RuntimeWarning)
                        means = np.nanmean([g[f"{key}_at_forces"] for g in grasps], axis=0)
                    print(f"{label:21s} {source:9s}  " + "  ".join(f"{v:7.3f}" for v in means))


def draw_contact_curves(curves: dict[str, dict[str, list]], key: str, path: Path) -> None:
    """One of :data:`CURVE_SERIES` against force, every grasp up to its force peak."""

    def loading(grasp: dict) -> tuple[np.ndarray, np.ndarray]:
        force = np.asarray(grasp["force_above_n"])
        peak = int(np.argmax(force)) + 1
        return force[:peak], np.asarray(grasp[key])[:peak]

    draw_per_object(curves, loading, "force above baseline [N]", CURVE_SERIES[key], path)


#: The frames' differences from 0.5 are shown this many times stronger in
#: :func:`draw_frames` (a faint imprint would not show otherwise).
FRAMES_GAIN = 3.0


def draw_frames(curves: dict[str, dict[str, list]], label: str, path: Path) -> None:
    """The difference images of one object's first real and first simulated grasp at
    :data:`CURVE_FORCES_N` (rows: real, generator), :data:`FRAMES_GAIN` times stronger."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sources = [s for s in ("real", "generator") if curves[s].get(label)]
    fig, axes = plt.subplots(
        len(sources), len(CURVE_FORCES_N), figsize=(12, 2.1 * len(sources)), squeeze=False
    )
    for row, source in zip(axes, sources, strict=True):
        for ax, force, frame in zip(
            row, CURVE_FORCES_N, curves[source][label][0]["frames_at_forces"], strict=True
        ):
            ax.set_axis_off()
            ax.set_title(f"{source}, {force:.0f} N", fontsize=9)
            if frame is not None:
                strong = (frame.astype(np.float32) - 127.5) * FRAMES_GAIN + 127.5
                ax.imshow(np.clip(strong, 0, 255).astype(np.uint8)[..., ::-1])  # BGR -> RGB
    fig.tight_layout()
    fig.savefig(path, dpi=64, pil_kwargs={"optimize": True})  # photographs: keep it small
    plt.close(fig)


def draw_per_object(
    curves: dict[str, dict[str, list]],
    xy: Callable[[dict], tuple[Any, Any]],
    xlabel: str,
    ylabel: str,
    path: Path,
) -> None:
    """One panel per object, every grasp's ``xy(grasp)`` curve: real (solid) and the
    generator (dashed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(OBJECTS), figsize=(15, 3.2), sharey=True)
    for ax, (label, _) in zip(axes, OBJECTS.values(), strict=True):
        for source, style in (("real", "-"), ("generator", "--")):
            for k, grasp in enumerate(curves[source].get(label, [])):
                color = "C0" if source == "real" else "C1"
                x, y = xy(grasp)
                ax.plot(x, y, style, color=color, lw=1, label=source if k == 0 else None)
        ax.set_title(label, fontsize=9)
        ax.set_xlabel(xlabel)
    axes[0].set_ylabel(ylabel)
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100, pil_kwargs={"optimize": True})
    plt.close(fig)


#: Gel variants of :func:`print_gel_mechanics`: the session gel of ``wedge-2023`` (its
#: median modulus, the middle of its 3.5-5.5 mm thickness range), then without the thin
#: layer's confinement, without the strain saturation, neither, a softer gel and a thick one.
GEL_VARIANTS = {
    "wedge-2023 gel": {},
    "no confinement": {"confinement_kappa": 1e9},
    "no saturation": {"max_strain": 5.0},
    "neither": {"confinement_kappa": 1e9, "max_strain": 5.0},
    "neither, 3e4 Pa": {"confinement_kappa": 1e9, "max_strain": 5.0, "modulus_pa": 3e4},
    "neither, h 20 mm": {"confinement_kappa": 1e9, "max_strain": 5.0, "thickness_mm": 20.0},
}


def print_gel_mechanics(radius_mm: float = 21.3) -> dict[str, list[float]]:
    """The generator's contact mechanics alone: the geometric contact area of a rigid ball
    (the golf ball's radius [mm]) as a share of the visible frame, at
    :data:`CURVE_FORCES_N`, for each of :data:`GEL_VARIANTS` (no rendering, no rig)."""
    from tactile_compliance.synthetic.geometry import PadGrid, Pose, ShapeSpec, sag_map
    from tactile_compliance.synthetic.mechanics import GelModel, ObjectMechanics, force_curve
    from tactile_compliance.synthetic.render import VISIBLE_SIZE_MM
    from tactile_compliance.synthetic.timeseries import RIGS

    grid = PadGrid(0.25)
    ball = ShapeSpec("Sphere", {"radius_mm": radius_mm}, thickness_mm=2 * radius_mm)
    sag = sag_map(ball, grid, Pose(offset_mm=(0.0, 0.0), angle_rad=0.0, tilt=(0.0, 0.0)))
    x, y = grid.coords()
    # The visible crop, where the images' contact share is counted.
    visible = (np.abs(x) < VISIBLE_SIZE_MM[0] / 2) & (np.abs(y) < VISIBLE_SIZE_MM[1] / 2)
    golf = ObjectMechanics(8.5e8, size_mm=2 * radius_mm)
    base = {"modulus_pa": RIGS["wedge-2023"].gel_modulus_pa, "thickness_mm": 4.5}
    forces = "  ".join(f"{f:5.0f} N" for f in CURVE_FORCES_N)
    print(f"geometric contact share of a rigid {radius_mm} mm ball\n{'gel':18s} {forces}  20/5 N")
    out = {}
    for name, changes in GEL_VARIANTS.items():
        curve = force_curve(sag, GelModel(**(base | changes)), golf, grid, max_force_n=30.0)
        approach = np.interp(CURVE_FORCES_N, curve.forces_n, curve.approaches_mm)
        out[name] = [float((visible & (sag < a)).mean() / visible.mean()) for a in approach]
        print(
            f"{name:18s} "
            + "  ".join(f"{v:7.3f}" for v in out[name])
            + f"  {out[name][3] / out[name][0]:6.2f}"
        )
    return out


def simulated_store(
    table: Path, seed: int, rig: GripperRig, out: Path, labels: list[str] | None = None
) -> Path:
    """The five objects simulated at the real crop's 250 x 350 px and imported."""
    from tactile_compliance.data.burgess import import_burgess
    from tactile_compliance.synthetic import generate_burgess_tree

    generate_burgess_tree(
        out / "raw",
        object_table=write_five_table(table, out / "five.csv", labels),
        grasps_per_object=3,
        seed=seed,
        image_size=(250, 350),
        progress=False,
        rig=rig,
    )
    import_burgess(out / "raw", out / "store", progress=False)
    return out / "store"


def print_image_stats(results: dict[str, dict[str, dict[str, float]]]) -> None:
    print(
        "\nobject                source     contact share  p99 |d| R  p99 |d| G  p99 |d| B"
        "  median |d| outside  edge glow  p99 away  depth max [mm]  elastic [Pa]  Hertz [Pa]"
        "  contact share at F1/F2/F3 [N]"
    )
    for label, _ in OBJECTS.values():
        for source in ("real", "generator"):
            row = results[source].get(label)
            if row:
                by_force = " ".join(
                    f"{share:.3f}@{force:.0f}"
                    for share, force in zip(
                        row["contact_share_by_frame"], row["force_by_frame_n"], strict=True
                    )
                )
                print(
                    f"{label:21s} {source:9s} {row['contact_share']:13.3f}  {row['p99_R']:9.3f}"
                    f"  {row['p99_G']:9.3f}  {row['p99_B']:9.3f}  {row['outside_median']:18.4f}"
                    f"  {row['edge_glow_grey']:9.1f}  {row['p99_away_from_edge']:8.3f}"
                    f"  {row['depth_max_mm']:14.2f}  {row['elastic_pa']:12.2e}"
                    f"  {row['hertz_pa']:10.2e}  {by_force}"
                )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--real", type=Path, default=REFERENCE / "real/wedge-grasps/2023-12-06")
    parser.add_argument(
        "--table", type=Path, default=REFERENCE / "dataset_objects_and_compliance.csv"
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--rig", default="dataset", help="the generator's rig (a name of RIGS or a rig file)"
    )
    # Overrides of the rig's fields, to fit them (docs/synthetic.md, "The gel").
    parser.add_argument("--gel-pa", type=float, help="the rig's gel modulus [Pa]")
    parser.add_argument("--finger-stiffness", help="the rig's K_f range LO,HI [N/m]")
    parser.add_argument("--glow-gain", help="the rig's edge glow gain range LO,HI")
    parser.add_argument("--light-balance", help="the rig's light balance G,R,B (factors)")
    parser.add_argument("--objects", help="comma-separated labels to simulate (default: all five)")
    parser.add_argument("--real-store", type=Path, help="store of the real grasps (images)")
    parser.add_argument(
        "--contact-figure", type=Path, help="with --real-store: contact share against force"
    )
    parser.add_argument(
        "--depth-figure", type=Path, help="with --real-store: depth peak against force"
    )
    parser.add_argument(
        "--radius-figure", type=Path, help="with --real-store: outer radius against force"
    )
    parser.add_argument(
        "--frames-figure", type=Path, help="with --real-store: one object's frames (PNG)"
    )
    parser.add_argument("--frames-object", default="golf_ball", help="the object they show")
    parser.add_argument(
        "--gel-mechanics",
        action="store_true",
        help="print the geometric contact share of a rigid golf ball on gel variants and exit",
    )
    parser.add_argument(
        "--background",
        type=Path,
        default=REFERENCE / "real/wedge-grasps/wedge_config/init_frame.png",
        help="the real warped no-contact frame (400 x 300 px)",
    )
    parser.add_argument(
        "--background-figure", type=Path, help="Draw the no-contact frames' profiles (PNG)."
    )
    parser.add_argument("--json", type=Path)
    parser.add_argument("--figure", type=Path, help="Draw force against closure (PNG).")
    args = parser.parse_args()
    if args.gel_mechanics:
        print_gel_mechanics()
        return
    if not args.real.is_dir():
        raise SystemExit(f"no real grasps at {args.real}")
    rig = chosen_rig(args)
    labels = args.objects.split(",") if args.objects else None
    results = {
        "rig": dataclasses.asdict(rig),
        "real": real_grasps(args.real),
        "generator": simulated_grasps(args.table, args.seed, rig, labels),
    }
    keys = [
        "F_peak_n",
        "contact_width_mm",
        "closure_10n_mm",
        "closure_peak_mm",
        "stiffness_n_per_mm",
    ]
    print(
        "object                source     F_peak [N]  contact W [mm]  close@10N [mm]"
        "  close@peak [mm]  k [N/mm]"
    )
    for label, _ in OBJECTS.values():
        for source in ("real", "generator"):
            rows = results[source].get(label, [])
            means = [np.nanmean([r[k] for r in rows]) if rows else np.nan for k in keys]
            print(f"{label:21s} {source:9s} " + "  ".join(f"{v:13.1f}" for v in means))
    if args.real_store:
        with tempfile.TemporaryDirectory() as tmp:
            synthetic = simulated_store(args.table, args.seed, rig, Path(tmp), labels)
            results["images"] = {
                "real": image_stats(args.real_store),
                "generator": image_stats(synthetic),
            }
        print_image_stats(results["images"])
        results["contact_curves"] = {
            "real": real_contact_curves(args.real, args.real_store.parent / "calibrations"),
            "generator": simulated_contact_curves(args.table, args.seed, rig, labels),
        }
        print_contact_curves(results["contact_curves"])
        if args.contact_figure:
            draw_contact_curves(results["contact_curves"], "contact_share", args.contact_figure)
        if args.depth_figure:
            draw_contact_curves(results["contact_curves"], "depth_peak_mm", args.depth_figure)
        if args.radius_figure:
            draw_contact_curves(results["contact_curves"], "outer_radius_mm", args.radius_figure)
        if args.frames_figure:
            draw_frames(results["contact_curves"], args.frames_object, args.frames_figure)
        for grasps in results["contact_curves"].values():  # images, not for the JSON
            for grasp in (g for per_object in grasps.values() for g in per_object):
                del grasp["frames_at_forces"]
    if args.background.is_file():
        results["backgrounds"] = backgrounds(args.background, args.seed, looks=4)
        print_backgrounds(results["backgrounds"])
        if args.background_figure:
            draw_backgrounds(results["backgrounds"], args.background_figure)
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n", encoding="utf-8")
    if args.figure:
        draw(results, args.figure)


def chosen_rig(args: argparse.Namespace) -> GripperRig:
    """The named rig (or rig file) with the fields the options override."""
    from tactile_compliance.synthetic.rig import resolve_rig

    def pair(text: str) -> tuple[float, float]:
        low, high = (float(v) for v in text.split(","))
        return (low, high)

    rig = resolve_rig(args.rig)[1]
    if args.gel_pa is not None:
        rig = dataclasses.replace(rig, gel_modulus_pa=args.gel_pa)
    if args.finger_stiffness:
        rig = dataclasses.replace(rig, finger_stiffness_n_per_m=pair(args.finger_stiffness))
    if args.glow_gain:
        rig = dataclasses.replace(rig, edge_glow_grey_per_mm=pair(args.glow_gain))
    if args.light_balance:
        balance = tuple(float(v) for v in args.light_balance.split(","))
        rig = dataclasses.replace(rig, light_balance=balance)  # type: ignore[arg-type]
    return rig


def draw(results: dict, path: Path) -> None:
    """Force above baseline against closure since contact."""
    draw_per_object(
        results,
        lambda grasp: (grasp["curve_closure_mm"], grasp["curve_force_n"]),
        "closure since contact [mm]",
        "force above baseline [N]",
        path,
    )


if __name__ == "__main__":
    main()
