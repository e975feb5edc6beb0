"""The one frame-selection/augmentation rule (data.frame_selection) and its two callers:
the synthetic generator (synthetic.timeseries.select_frames) and recording your own
grasps (acquisition.recording.augmented_indices)."""

from __future__ import annotations

import numpy as np
import pytest

from tactile_compliance.acquisition.recording import augmented_indices
from tactile_compliance.data.frame_selection import (
    augment_selection,
    select_frame_indices,
    selection_window,
)
from tactile_compliance.synthetic.timeseries import select_frames


def _ramp(n: int = 40, onset: int = 6, rise: int = 15) -> np.ndarray:
    t = np.arange(n, dtype=float)
    return 60.0 * np.clip((t - onset + 1) / rise, 0, 1) ** 1.5


def test_generator_and_recording_refuse_the_same_two_frame_press() -> None:
    # The force jumps from below 5 N to its peak within one frame: three distinct frames
    # cannot be chosen. The generator used to keep such a grasp with a repeated frame
    # (its own copy of the rule allowed i_peak = i_start + 1) while the recording refused it.
    force = np.array([0.0, 1.0, 3.0, 30.0, 60.0, 60.0, 60.0, 60.0, 60.0, 0.0])
    depth = np.clip(force / 60.0, 0.0, None)
    assert select_frame_indices(force) is None
    assert selection_window(force) is None
    assert select_frames(force, depth, depth, label_pa=1e4) is None
    with pytest.raises(ValueError, match="no frame selection"):
        augmented_indices(force)


def test_both_callers_pick_what_the_one_rule_picks() -> None:
    rng = np.random.default_rng(0)
    for _ in range(200):
        force = _ramp(rise=int(rng.integers(3, 25))) + rng.normal(0.0, 1.0, 40)
        force[int(rng.integers(20, 40)) :] *= rng.uniform(0.5, 1.0)
        depths = [np.clip(force, 0, None) / 60.0 * rng.uniform(0.5, 2.0) for _ in range(2)]
        modulus_pa = float(10 ** rng.uniform(3.0, 7.0))
        rule = augment_selection(force, max_depth_mm=depths, modulus_pa=modulus_pa)
        generator = select_frames(force, depths[0], depths[1], label_pa=modulus_pa)
        if rule is None:
            assert generator is None
            continue
        assert generator is not None and generator.num_aug == rule.num_aug
        for mine, theirs in zip(generator.fingers, rule.fingers, strict=True):
            np.testing.assert_array_equal(mine, theirs)
        np.testing.assert_array_equal(generator.force, rule.force)
        flat = augment_selection(
            force, max_depth_mm=depths, modulus_pa=modulus_pa, contact_shift=False
        )
        assert flat is not None
        assert augmented_indices(force, modulus_pa=modulus_pa, max_depth_mm=depths) == (
            flat.augmentations()
        )


def test_contact_shift_moves_each_fingers_first_frame() -> None:
    force = _ramp()
    base = select_frame_indices(force)
    assert base is not None
    onset = base.onset
    # Finger 0 touches two frames after the force onset, finger 1 at the onset.
    late = np.where(np.arange(force.size) >= onset + 2, 1.0, 0.0)
    early = np.where(np.arange(force.size) >= onset, 1.0, 0.0)
    sel = augment_selection(force, max_depth_mm=[late, early], modulus_pa=1e4)
    assert sel is not None
    assert tuple(sel.fingers[0]) == (base.indices[0] + 2, *base.indices[1:])
    assert tuple(sel.fingers[1]) == base.indices
    assert tuple(sel.force) == base.indices  # the forces move by the smaller shift
    # Without depths (or with contact_shift=False) every finger keeps the base frames.
    assert tuple(augment_selection(force).fingers[0]) == base.indices  # type: ignore[union-attr]
    flat = augment_selection(force, max_depth_mm=[late, early], contact_shift=False)
    assert flat is not None and all(tuple(v) == base.indices for v in flat.fingers)


def test_timestamps_choose_augmentation_zero_in_time() -> None:
    force = _ramp()
    times = np.arange(force.size) / 30.0
    times[10:] += 0.2  # frames dropped early in the press
    timed = augment_selection(force, timestamps_s=times)
    by_index = augment_selection(force)
    assert timed is not None and by_index is not None
    assert timed.base.indices == select_frame_indices(force, timestamps_s=times).indices  # type: ignore[union-attr]
    assert timed.base.indices != by_index.base.indices
    assert timed.augmentations()[1] == tuple(i + 1 for i in timed.base.indices)
