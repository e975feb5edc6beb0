"""Grasp time series and the published frame-selection rules."""

from __future__ import annotations

import numpy as np
import pytest

from tactile_compliance.synthetic.geometry import PadGrid, Pose, ShapeSpec, sag_map
from tactile_compliance.synthetic.mechanics import GelModel, ObjectMechanics, force_curve
from tactile_compliance.synthetic.rng import stream
from tactile_compliance.synthetic.timeseries import (
    FPS,
    select_frames,
    selection_window,
    simulate_timeline,
)


def _timeline(modulus_pa: float, seed: int = 0, **kwargs: object):  # type: ignore[no-untyped-def]
    grid = PadGrid(0.5)
    spec = ShapeSpec("Sphere", {"radius_mm": 20.0}, 40.0)
    sag = sag_map(spec, grid, Pose((0.0, 0.0), 0.0, (0.0, 0.0)))
    obj = ObjectMechanics(modulus_pa, 0.45, 40.0, 0.6)
    curve = force_curve(sag, GelModel(), obj, grid)
    return simulate_timeline((curve, curve), 0.040, 3e5, float("inf"), stream(seed, "t"), **kwargs)


def test_force_ramp_hold_and_widths() -> None:
    tl = _timeline(1e9)
    assert np.all(np.abs(np.diff(tl.times_s) - 1 / FPS) < 0.01)  # 30 fps, jittered
    assert 54.0 < tl.force_true_n.max() < 67.0  # F_t ~ N(60, 2) plus ~1 % ripple
    # In contact, width and approach are monotone functions of the force.
    touching = tl.force_true_n > 0
    order = np.argsort(tl.force_true_n[touching])
    assert np.all(np.diff(tl.width_true_m[touching][order]) <= 1e-12)
    assert np.all(np.diff(tl.approach_mm[:, touching][:, order], axis=1) >= -1e-9)
    # The measured width is stair-stepped: runs of repeated readings.
    assert np.any(np.diff(tl.width_m) == 0)
    assert tl.width_m.max() <= 0.08


def test_soft_objects_squeeze_more_and_load_longer() -> None:
    hard, soft = _timeline(1e10), _timeline(1e5)
    squeeze = [0.040 - t.width_true_m.min() for t in (hard, soft)]
    assert squeeze[1] > 2 * squeeze[0]
    loading = [
        int(np.argmax(t.force_true_n >= 0.975 * t.force_true_n.max())) - t.contact_frame
        for t in (hard, soft)
    ]
    assert loading[1] > loading[0]


def test_selection_rules_on_a_known_ramp() -> None:
    forces = np.concatenate([np.zeros(3), np.linspace(0, 60, 21), np.full(12, 60.0), [30, 5, 0]])
    depth = np.clip(forces / 60.0, 0, None) ** 0.5
    window = selection_window(forces)
    assert window is not None
    i_start, i_peak, i_end = window
    assert forces[i_start] >= 5.0 > forces[i_start - 1]
    assert forces[i_peak - 1] >= 0.975 * 60.0 > forces[i_peak - 2]
    assert i_end == i_peak + 5
    sel = select_frames(forces, depth, depth, label_pa=1e6)
    assert sel is not None
    np.testing.assert_array_equal(sel.fingers[0], np.linspace(i_start, i_peak - 1, 3).astype(int))
    np.testing.assert_array_equal(sel.force, sel.fingers[0])
    assert sel.num_aug == 5  # the hold keeps F >= 0.95 F_max for the next four frames
    assert set(sel.frames_needed()) == {int(v) + k for v in sel.fingers[0] for k in range(5)}


def test_selection_stops_augmenting_when_the_force_drops() -> None:
    forces = np.concatenate([np.zeros(2), np.linspace(0, 60, 16), [59.0, 50.0, 40.0, 0.0, 0.0]])
    depth = np.clip(forces / 60.0, 0, None)
    sel = select_frames(forces, depth, depth, label_pa=1e6)
    assert sel is not None
    assert sel.num_aug == 2


def test_selection_skips_weak_grasps() -> None:
    forces = np.concatenate([np.zeros(3), np.linspace(0, 9, 10)])
    assert select_frames(forces, forces, forces, label_pa=1e6) is None


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_timeline_is_deterministic(seed: int) -> None:
    a, b = _timeline(1e7, seed), _timeline(1e7, seed)
    np.testing.assert_array_equal(a.force_n, b.force_n)
    np.testing.assert_array_equal(a.width_m, b.width_m)


def test_the_controller_presses_to_the_rig_s_force() -> None:
    tl = _timeline(1e9, peak_force_n=(23.0, 0.0))
    assert 22.0 < tl.force_true_n.max() < 24.0  # 23 N plus ~1 % ripple
