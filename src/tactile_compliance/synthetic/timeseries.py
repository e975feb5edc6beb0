"""Grasp time series (force, width, approach per frame) and the real frame-selection rules.

See docs/synthetic.md, "Time series and frame selection".
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tactile_compliance.data.frame_selection import (
    MAX_AUGMENTATIONS,
    AugmentedSelection,
    augment_selection,
    selection_window,
)
from tactile_compliance.synthetic.mechanics import ContactCurve

# The rig moved to synthetic/rig.py (a file since calibrate-rig); kept importable here.
from tactile_compliance.synthetic.rig import DATASET_RIG, RIGS, WEDGE_2023_RIG, GripperRig

__all__ = [
    "DATASET_RIG",
    "FPS",
    "RIGS",
    "WEDGE_2023_RIG",
    "GraspTimeline",
    "GripperRig",
    "select_frames",
    "selection_window",
    "simulate_timeline",
]

FPS = 30.0
"""Camera frame rate [1/s]."""

CLOSING_SPEED_M_S = 0.0375
"""Gripper closing speed [m/s]."""

OPEN_WIDTH_M = 0.08
"""Gripper width when the grasp starts [m]."""


@dataclass
class GraspTimeline:
    """One simulated grasp, frame by frame (all arrays shape (T,)).

    Attributes:
        times_s: frame timestamps [s].
        force_true_n: true normal force [N].
        approach_mm: approach of each finger, shape (2, T) [mm] (<= 0: no contact).
        width_true_m: true gripper width [m].
        force_n: measured force [N] (what forces.pkl stores).
        width_m: measured width [m], stair-stepped (what widths.pkl stores).
        contact_frame: index of the first frame in contact.
    """

    times_s: np.ndarray
    force_true_n: np.ndarray
    approach_mm: np.ndarray
    width_true_m: np.ndarray
    force_n: np.ndarray
    width_m: np.ndarray
    contact_frame: int


def simulate_timeline(
    curves: tuple[ContactCurve, ContactCurve],
    contact_width_m: float,
    finger_stiffness_n_per_m: float,
    shell_stiffness_n_per_m: float,
    rng: np.random.Generator,
    settle_probability: float = 0.35,
    peak_force_n: tuple[float, float] = DATASET_RIG.peak_force_n,
    force_baseline_sd_n: float = DATASET_RIG.force_baseline_sd_n,
) -> GraspTimeline:
    """Simulate the force/width/approach time series of one grasp.

    Args:
        curves: force-approach curves of the two fingers.
        contact_width_m: gripper width at first contact (object size) [m].
        finger_stiffness_n_per_m: finger/mount stiffness K_f [N/m].
        shell_stiffness_n_per_m: shell stiffness per contact [N/m] (inf if solid).
        rng: the grasp's time-series stream.
        settle_probability: probability that the object seats by 0.2-1.5 mm while
            loading (0 for a perfectly stable grasp, e.g. a sphere).
        peak_force_n: mean and standard deviation of the controller's target force [N].
        force_baseline_sd_n: sd of the force reading's offset [N] (the rig's).
    """
    target_n = float(rng.normal(*peak_force_n))
    q = float(rng.uniform(1.5, 3.0))
    shell_c = 0.0 if not np.isfinite(shell_stiffness_n_per_m) else 1.0 / shell_stiffness_n_per_m
    finger_c = 1.0 / finger_stiffness_n_per_m
    # A shell flattens until its walls meet: cap its deflection per contact smoothly at
    # 15 % of the object's size.
    shell_max_m = 0.15 * contact_width_m

    def closure_m(force: np.ndarray) -> np.ndarray:
        approach = curves[0].approach_at(force) + curves[1].approach_at(force)
        linear = force * shell_c
        shell = linear / (1.0 + linear / shell_max_m)
        return approach * 1e-3 + force * finger_c + 2.0 * shell

    # Seating: many grasps settle while loading (the object rotates or slides into a
    # stable pose, rough contacts bed in), an extra closure that grows with the force
    # and has nothing to do with the modulus.
    settle_m = float(rng.uniform(0.2e-3, 1.5e-3)) if rng.random() < settle_probability else 0.0
    settle_force = float(rng.uniform(10.0, 40.0))

    def seating_m(force: np.ndarray) -> np.ndarray:
        return settle_m * (1.0 - np.exp(-np.asarray(force) / settle_force))

    at_target = np.array([target_n])
    closure_target = float(closure_m(at_target)[0] + seating_m(at_target)[0])
    # Controller time U(0.3, 0.7) s (the design notes say 0.15-0.5 s; the longer range
    # reproduces the real ~4.6 augmentations per grasp, see docs/synthetic.md).
    t_load = float(rng.uniform(0.3, 0.7)) + closure_target / CLOSING_SPEED_M_S
    t_hold = float(rng.uniform(0.45, 0.7))
    t_release = float(rng.uniform(0.1, 0.25))
    t_pre = float(rng.uniform(0.2, 0.6))
    t_post = float(rng.uniform(0.05, 0.12))
    total = t_pre + t_load + t_hold + t_release + t_post
    n_frames = int(np.ceil(total * FPS))
    times = np.arange(n_frames) / FPS + rng.normal(0.0, 0.002, n_frames)
    # Ripple during the hold: a few slow sinusoids, ~1 % of the force.
    freqs = rng.uniform(1.5, 8.0, 3)
    phases = rng.uniform(0, 2 * np.pi, 3)
    ripple_amp = float(rng.uniform(0.005, 0.012))

    def force_at(t: np.ndarray) -> np.ndarray:
        u = (t - t_pre) / t_load
        f = np.where(u > 0, target_n * (1.0 - (1.0 - np.clip(u, 0.0, 1.0)) ** q), 0.0)
        t_h0, t_h1 = t_pre + t_load, t_pre + t_load + t_hold
        ripple = np.sum(
            np.sin(2 * np.pi * freqs[:, None] * (t - t_h0)[None, :] + phases[:, None]), axis=0
        )
        ramp_in = np.clip((t - t_h0) / 0.1, 0.0, 1.0)  # ripple fades in with the hold
        f = np.where(t >= t_h0, target_n * (1.0 + ripple_amp * ripple / 1.7 * ramp_in), f)
        v = np.clip((t - t_h1) / t_release, 0.0, 1.0)
        f = np.where(t >= t_h1, f * (1.0 - v) ** 1.5, f)
        return np.maximum(f, 0.0)

    force_true = force_at(times)
    in_contact = force_true > 0
    approach = np.stack([c.approach_at(np.maximum(force_true, 1e-9)) for c in curves])
    # Before contact (and after release) the finger is still short of the object.
    gap_mm = np.where(
        times < t_pre,
        (t_pre - times) * CLOSING_SPEED_M_S * 1e3,
        (times - (total - t_post)) * CLOSING_SPEED_M_S * 1e3,
    )
    approach = np.where(in_contact[None, :], approach, -np.maximum(gap_mm, 1e-3)[None, :] / 2)
    positive = np.maximum(force_true, 1e-9)
    squeeze_m = np.where(in_contact, closure_m(positive) + seating_m(positive), 0.0)
    width_true = np.where(
        in_contact,
        contact_width_m - squeeze_m,
        np.minimum(contact_width_m + np.maximum(gap_mm, 0.0) * 1e-3, OPEN_WIDTH_M),
    )
    # A thin object ends up embedded in both gels: the gel surfaces cannot pass each other.
    width_true = np.maximum(width_true, 0.2e-3)
    # Measured force: gain/offset error, latency, noise.
    gain = float(rng.normal(1.0, 0.02))
    offset = float(rng.normal(0.0, force_baseline_sd_n))
    latency = float(rng.uniform(0.0, 0.04))
    force_meas = force_at(times - latency) * gain + offset + rng.normal(0.0, 0.05, n_frames)
    # Measured width: reported asynchronously (latency), calibration offset, noise,
    # 50 um encoder steps, updated every 2-4 frames.
    width_latency = float(rng.uniform(0.0, 0.05))
    lagged = np.interp(times - width_latency, times, width_true)
    hold_frames = int(rng.integers(2, 5))
    phase = int(rng.integers(0, hold_frames))
    readings = lagged - 0.5e-3 + rng.normal(0.0, 15e-6, n_frames)
    readings = np.round(readings / 50e-6) * 50e-6
    update = (np.arange(n_frames) + phase) // hold_frames
    first_of_block = np.searchsorted(update, update)
    width_meas = readings[first_of_block]
    contact_frame = int(np.argmax(in_contact)) if in_contact.any() else n_frames
    return GraspTimeline(
        times_s=times,
        force_true_n=force_true,
        approach_mm=approach,
        width_true_m=width_true,
        force_n=force_meas,
        width_m=width_meas,
        contact_frame=contact_frame,
    )


def select_frames(
    forces_n: np.ndarray,
    max_depth_mm: np.ndarray,
    max_depth_markers_mm: np.ndarray,
    label_pa: float,
    max_aug: int = MAX_AUGMENTATIONS,
) -> AugmentedSelection | None:
    """The published three-frame selection and time-shift augmentations of a simulated
    grasp (``data.frame_selection.augment_selection``, on the generator's two fingers).

    Args:
        forces_n: measured force of the whole recording [N].
        max_depth_mm: per-frame maximum reconstructed depth, markerless finger [mm]
            (only the frames of the selection window are read).
        max_depth_markers_mm: the same for the marker finger [mm].
        label_pa: the object's label; the original code stops augmenting objects of
            >= 5e5 Pa whose first frame is already >= 80 % as deep as the last.
        max_aug: maximum number of augmentations.

    Returns:
        ``fingers`` = (markerless, marker) frames of augmentation 0, or None when the
        grasp has no selection.
    """
    return augment_selection(
        forces_n,
        max_depth_mm=(max_depth_mm, max_depth_markers_mm),
        modulus_pa=label_pa,
        max_aug=max_aug,
    )
