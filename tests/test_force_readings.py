"""Real-data quirks of the robot's readings, on synthetic readings (fast, no real data).

Each quirk of the real rig (``../shared/reference-data/real/README.md``) is made here on
purpose and must be handled and reported, never silently used and never a crash:
single-frame force spikes, a force baseline that is not zeroed, a recording that starts
in light contact (so its first frame is no reference), and long recordings (223 frames).
``tests/test_real_grasps.py`` checks the same on the real recordings when present.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from tactile_compliance.acquisition.capture import capture_grasp
from tactile_compliance.acquisition.first_frame import reference_frame
from tactile_compliance.acquisition.readings import Readings, write_readings_csv
from tactile_compliance.acquisition.recording import ObjectInfo, record_grasp
from tactile_compliance.acquisition.sensors import (
    PLAIN_GEOMETRY,
    FrameGeometry,
    FrameSizeError,
    FrameSourceBase,
)
from tactile_compliance.cli import app
from tactile_compliance.data.force_readings import (
    CONTACT_MARGIN_N,
    find_force_spikes,
    force_baseline,
)
from tactile_compliance.data.image_ops import difference_images
from tactile_compliance.data.safe_pickle import load_numpy_pickle
from tactile_compliance.inference.live import format_live_event, live_estimates

FPS = 30.0
SIZE = (60, 84)
runner = CliRunner()


def hold_grasp(n=60, onset=10, rise=12, hold=25, peak=24.0, offset=0.0):
    """A grasp's force: flat, a ramp to ``peak``, a hold, a fast release, flat again."""
    t = np.arange(n, dtype=float)
    force = peak * np.clip((t - onset) / rise, 0, 1)
    force[onset + rise + hold :] = 0.0
    return force + offset


# ---------------------------------------------------------------------- spikes
def test_a_single_frame_spike_is_replaced_by_its_neighbours_median():
    force = hold_grasp()
    spiked = force.copy()
    spiked[30] = -70.0  # in the hold: left in, it would end the capture as a release
    spiked[40] = 55.0  # and a positive one would move F_max
    cleaned, spikes = find_force_spikes(spiked, np.arange(60) / FPS)
    assert [s.index for s in spikes] == [30, 40]
    assert spikes[0].force_n == -70.0 and spikes[0].replaced_n == pytest.approx(24.0)
    assert spikes[0].timestamp_s == pytest.approx(1.0)
    np.testing.assert_allclose(cleaned, force)
    assert "reading 30 at 1.0000 s, frame 30: -70.00 N replaced by 24.00 N" in spikes[0].describe(
        30
    )


def test_steps_ramps_noise_and_ends_are_not_spikes():
    rng = np.random.default_rng(0)
    force = hold_grasp() + rng.normal(0, 0.05, 60)  # the generator's noise
    steep = np.r_[np.zeros(5), np.arange(1, 8) * 9.0, np.full(10, 63.0), np.zeros(5)]
    for series in (force, steep, np.array([24.0, 24.0, 0.0, 0.0]), np.array([0, 1, 30.0])):
        cleaned, spikes = find_force_spikes(series)
        assert spikes == [] and np.array_equal(cleaned, series)
    # A spike on the first or last reading cannot be told from a step; two frames are no
    # single-frame spike: both are left as read.
    ends = hold_grasp()
    ends[0], ends[-1] = -70.0, 40.0
    two = hold_grasp()
    two[30:32] = -70.0
    assert find_force_spikes(ends)[1] == [] and find_force_spikes(two)[1] == []


def test_readings_replace_spikes_so_the_capture_does_not_stop_early(grasp):
    force = grasp["force"].copy()
    hold = int(np.argmax(force)) + 2
    force[hold] = -70.0
    readings = Readings(grasp["times"], force, grasp["width"])
    assert [s.index for s in readings.spikes] == [hold]
    assert readings.raw_force_n[hold] == -70.0
    assert readings(grasp["times"][hold])[0] == pytest.approx(readings.force_n[hold])
    clean = capture_grasp(ArraySource(grasp["frames"]), Readings(*grasp["readings"]))
    captured = capture_grasp(ArraySource(grasp["frames"]), readings)
    assert len(captured) == len(clean) > hold + 1
    np.testing.assert_allclose(captured.force_n, clean.force_n, atol=0.5)


# ---------------------------------------------------------------------- baseline
def test_the_baseline_comes_from_the_flat_ends_and_is_not_subtracted():
    both = force_baseline(hold_grasp(offset=0.4))
    assert both.start_n == pytest.approx(0.4) and both.end_n == pytest.approx(0.4)
    assert both.baseline_n == pytest.approx(0.4) and both.contact_n(0.45) is None
    # Starting in light contact (rising from 1.2 N): only the end is flat.
    rising = hold_grasp(onset=-1, offset=0.0)
    rising[:10] += np.linspace(1.2, 3.0, 10)
    late = force_baseline(rising + 0.2)
    assert late.start_n is None and late.baseline_n == pytest.approx(0.2)
    assert late.contact_n(1.4) == pytest.approx(1.2)
    # A flat start in light contact (0.3 N) above an empty end: the lower level is the
    # baseline, since contact only adds force.
    light = hold_grasp()
    light[:10] = 0.3
    assert force_baseline(light).baseline_n == pytest.approx(0.0)
    # Neither end flat: unknown, and contact is judged against the lowest reading.
    unknown = force_baseline(np.r_[np.linspace(1, 24, 20), np.linspace(24, 0.5, 10)])
    assert unknown.baseline_n is None and unknown.level_n == pytest.approx(0.5)
    assert "unknown" in unknown.describe() and unknown.margin_n >= CONTACT_MARGIN_N
    readings = Readings(np.arange(60) / FPS, hold_grasp(offset=0.4), np.full(60, 0.05))
    np.testing.assert_array_equal(readings.force_n, hold_grasp(offset=0.4))  # not subtracted


# ---------------------------------------------------------------------- record
class ArraySource(FrameSourceBase):
    """Frames from memory at a constant rate (a replay, like a video file)."""

    def __init__(self, frames, geometry: FrameGeometry = PLAIN_GEOMETRY, name="array"):
        super().__init__(geometry)
        self.frames, self.i, self.name = frames, 0, name

    def _grab(self):
        if self.i >= len(self.frames):
            return None
        self.i += 1
        return (self.i - 1) / FPS, self.frames[self.i - 1]


@pytest.fixture(scope="module")
def grasp():
    """A synthetic camera recording at 30 fps: frames, readings, the no-contact frame."""
    from tactile_compliance.synthetic.grasp import SimulationOptions, make_context
    from tactile_compliance.synthetic.objects import default_objects
    from tactile_compliance.synthetic.trajectories import camera_recording

    spec = default_objects(3, seed=4)[1]
    rec = camera_recording(make_context(spec, 4, SimulationOptions(image_size=SIZE)), 0)
    times = np.arange(len(rec.frames)) / FPS
    return {
        "frames": rec.frames,
        "reference": rec.reference,
        "times": times,
        "force": rec.force_n,
        "width": rec.width_m,
        "readings": (times, rec.force_n, rec.width_m),
        "info": ObjectInfo(spec.name, rec.modulus_pa),
    }


def _started_in_contact(grasp, skip):
    """The same grasp, recorded from frame ``skip`` on (already pressing)."""
    times, force, width = grasp["readings"]
    return grasp["frames"][skip:], Readings(times[skip:] - times[skip], force[skip:], width[skip:])


def test_record_reports_spikes_with_their_frame_and_the_baseline(grasp, tmp_path):
    times, force, width = grasp["readings"]
    force = force + 0.8  # an unzeroed sensor, beyond the +-0.5 N that record tolerates
    spike = int(np.argmax(force)) + 2
    force[spike] = -70.0
    result = record_grasp(
        ArraySource(grasp["frames"]), Readings(times, force, width), tmp_path, grasp["info"]
    )
    assert [s["frame"] for s in result.checks["spikes"]] == [spike]
    assert any(f"frame {spike}: -70.00 N replaced by" in w for w in result.warnings)
    # The generator's own offset (0.1 N here) plus 0.8 N.
    assert result.checks["baseline"]["baseline_n"] == pytest.approx(0.9, abs=0.05)
    assert any("baseline +0.9" in w and "zero the force sensor" in w for w in result.warnings)
    text = result.format()
    assert (
        "Force       no-contact force baseline +0.9" in text and "Warning     force spike" in text
    )
    assert json.loads(json.dumps(result.to_dict()))["warnings"] == result.warnings


def test_a_recording_that_starts_in_contact_warns_and_takes_an_explicit_reference(grasp, tmp_path):
    onset = int(np.argmax(grasp["force"] >= 1.0))
    frames, readings = _started_in_contact(grasp, onset + 1)
    plain = record_grasp(ArraySource(frames), readings, tmp_path / "a", grasp["info"])
    assert plain.checks["first_frame_contact_n"] > 1.0
    assert any("starts in contact" in w and "--reference IMAGE" in w for w in plain.warnings)
    # With the no-contact frame as the reference the warning goes, and the difference
    # images are taken against it, not against the pressed first frame.
    fixed = record_grasp(
        ArraySource(frames), readings, tmp_path / "b", grasp["info"], reference=grasp["reference"]
    )
    assert not any("starts in contact" in w for w in fixed.warnings)
    assert fixed.checks["reference"] == "--reference"
    rgb = load_numpy_pickle(fixed.path / "augmentation=0" / "RGB.pkl")
    expected = difference_images(frames, grasp["reference"])[list(fixed.frame_indices[0])]
    np.testing.assert_array_equal(rgb, expected)


def test_a_reference_camera_frame_goes_through_the_geometry_and_sizes_are_checked(grasp):
    geometry = FrameGeometry(crop_px=4)
    camera = grasp["reference"]
    cut = reference_frame(camera, geometry, (SIZE[0] - 8, SIZE[1] - 8, 3))
    np.testing.assert_array_equal(cut, camera[4:-4, 4:-4])
    assert reference_frame(cut, geometry, cut.shape) is cut  # already a sensor frame
    with pytest.raises(FrameSizeError, match=r"reference image is 30x40 px"):
        reference_frame(camera[:30, :40], geometry, cut.shape)


def test_a_reference_from_elsewhere_or_in_rgb_order_is_reported(grasp, tmp_path):
    frames = grasp["frames"]
    swapped = np.ascontiguousarray(grasp["reference"][..., ::-1])
    if np.abs(swapped.astype(int) - grasp["reference"]).mean() < 10:
        pytest.skip("this synthetic gel is too grey for a channel swap to show")
    result = record_grasp(
        ArraySource(frames),
        Readings(*grasp["readings"]),
        tmp_path,
        grasp["info"],
        reference=swapped,
    )
    assert any("red and blue swapped" in w for w in result.warnings), result.warnings


def test_a_long_recording_of_223_frames_records_and_streams(grasp, tmp_path):
    """223 frames (the real rig's longest): a long empty lead-in, the grasp, a long hold."""
    from tactile_compliance.inference.estimator import ComplianceEstimator
    from tactile_compliance.inference.streaming import predict_trajectory

    _, force, width = grasp["readings"]
    peak = int(np.argmax(force))
    lead = 223 - len(force) - 40
    order = np.r_[
        np.zeros(lead, int), np.arange(peak + 1), np.full(40, peak), np.arange(peak + 1, len(force))
    ]
    assert order.size == 223
    frames, long_t = grasp["frames"][order], np.arange(223) / FPS
    readings = Readings(long_t, force[order], width[order])
    result = record_grasp(ArraySource(frames), readings, tmp_path / "data", grasp["info"])
    assert result.n_frames > lead + 40 and result.frame_indices[0][0] >= lead
    from test_recording import _checkpoint

    estimator = ComplianceEstimator.from_checkpoint(_checkpoint(tmp_path / "m.pt"))
    events = list(live_estimates([estimator], ArraySource(frames), readings))
    final = events[-1]
    assert final["final"] and final["frame_indices"] == list(result.frame_indices[0])
    assert final["frames_seen"] == result.n_frames
    expected, _ = predict_trajectory(
        estimator,
        frames[: result.n_frames],
        readings.force_n[: result.n_frames],
        readings.width_m[: result.n_frames],
        frame_kind="raw",
        channel_order="BGR",
    )
    assert final["log10_modulus_pa"] == pytest.approx(expected.log10_modulus_pa, abs=1e-5)


def test_live_reports_spikes_and_a_start_in_contact(grasp, tmp_path):
    from tactile_compliance.inference.estimator import ComplianceEstimator
    from test_recording import _checkpoint

    onset = int(np.argmax(grasp["force"] >= 1.0))
    frames, readings = _started_in_contact(grasp, onset + 1)
    force = readings.raw_force_n.copy()
    spike = int(np.argmax(force)) + 2
    force[spike] = -70.0
    spiked = Readings(readings.timestamp_s, force, readings.width_m)
    estimator = ComplianceEstimator.from_checkpoint(_checkpoint(tmp_path / "m.pt"))
    events = list(live_estimates([estimator], ArraySource(frames), spiked))
    warnings = [e["reason"] for e in events if e["event"] == "warning"]
    assert any("starts in contact" in w for w in warnings)
    assert sum(f"reading {spike} " in w for w in warnings) == 1
    assert format_live_event(events[0]).startswith("warning     ")
    # The spike did not end the stream early: the same final as without it.
    clean = list(live_estimates([estimator], ArraySource(frames), readings))
    assert events[-1]["final"] and events[-1]["frame_indices"] == clean[-1]["frame_indices"]


def test_the_record_command_takes_a_reference_image(grasp, tmp_path):
    import cv2

    onset = int(np.argmax(grasp["force"] >= 1.0))
    frames, readings = _started_in_contact(grasp, onset + 1)
    folder = tmp_path / "frames"
    folder.mkdir()
    for i, frame in enumerate(frames):
        cv2.imwrite(str(folder / f"{i:04d}.png"), frame)
    csv = write_readings_csv(
        tmp_path / "r.csv", readings.timestamp_s, readings.force_n, readings.width_m
    )
    cv2.imwrite(str(tmp_path / "empty.png"), grasp["reference"])
    common = ["record", f"folder:{folder}", "--fps", FPS, "--readings", csv, "--out"]
    info = ["--object", grasp["info"].name, "--modulus", grasp["info"].modulus_pa]
    plain = runner.invoke(app, [str(a) for a in [*common, tmp_path / "a", *info]])
    assert plain.exit_code == 0, plain.output
    assert "Warning     the recording starts in contact" in plain.output
    fixed = runner.invoke(
        app,
        [str(a) for a in [*common, tmp_path / "b", *info, "--reference", tmp_path / "empty.png"]],
    )
    assert fixed.exit_code == 0, fixed.output
    assert "starts in contact" not in fixed.output
    bad = runner.invoke(app, [str(a) for a in [*common, tmp_path / "c", *info, "--reference", csv]])
    assert bad.exit_code == 2 and "not an image file" in bad.output
