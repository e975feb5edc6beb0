"""Recording your own grasps and the live estimate, end to end through a replayed camera.

A synthetic grasp (``synthetic.trajectories.camera_recording``) is written as an MJPG video
at 15 fps with a readings CSV; the same ``VideoCapture`` code path that reads a camera
then feeds ``calibrate``, ``record``, ``import burgess``, ``predict`` and ``live``.

Tolerance of "live equals predict": 1e-5 decades. Both paths see bit-identical inputs
(the same decoded video frames, the same interpolated readings, the same uint8
difference images), so only float32 round-off of batched kernels (5 samples at once in
``predict``, one in ``live``) may differ.
"""

from __future__ import annotations

import json
import time

import cv2
import numpy as np
import pandas as pd
import pytest

from helpers import (
    REPLAY_FPS,
    REPLAY_SIZE,
    ArraySource,
    cli,
    decoded,
    json_lines,
    make_replay_grasp,
    runner,
    top10nn_checkpoint,
)
from tactile_compliance.acquisition.readings import ReadingError, Readings, write_readings_csv
from tactile_compliance.acquisition.recording import ObjectInfo, augmented_indices, record_grasp
from tactile_compliance.acquisition.sensors import open_source
from tactile_compliance.cli import app
from tactile_compliance.data.image_ops import difference_images
from tactile_compliance.data.photometric import reconstruct_depth
from tactile_compliance.data.safe_pickle import load_numpy_pickle
from tactile_compliance.data.store import GraspStore
from tactile_compliance.inference.live import format_live_event
from tactile_compliance.physics.dataset_estimates import dataset_estimates_pa


@pytest.fixture(scope="module")
def grasp(tmp_path_factory):
    return make_replay_grasp(tmp_path_factory.mktemp("grasp"), REPLAY_SIZE)


# ---------------------------------------------------------------------- readings
def test_readings_interpolate_to_frame_times_and_refuse_the_rest(tmp_path):
    readings = Readings(np.array([0.0, 1.0, 2.0]), np.array([0.0, 10.0, 30.0]), np.full(3, 0.05))
    assert readings(0.5) == (5.0, 0.05)
    assert readings(1.5)[0] == pytest.approx(20.0)
    with pytest.raises(ReadingError, match=r"no force/width reading at 2\.5000 s"):
        readings(2.5)
    assert Readings(readings.timestamp_s, readings.force_n, readings.width_m, 0.6)(2.5)[0] == 30
    path = tmp_path / "r.csv"
    path.write_text("timestamp_s,force_n\n0,1\n")
    with pytest.raises(ValueError, match=r"missing column\(s\) \['width_m'\]"):
        Readings.from_csv(path)
    with pytest.raises(ValueError, match="timestamps must increase"):
        Readings([0.0, 1.0, 1.0], [0, 1, 2], [0.05] * 3)


# ---------------------------------------------------------------------- selection
def _ramp(n=50, onset=8, rise=20, hold_drop=None):
    t = np.arange(n, dtype=float)
    force = 60.0 * np.clip((t - onset + 2) / rise, 0, 1) ** 1.5
    if hold_drop is not None:
        force[hold_drop:] *= 0.9  # leaves the >= 0.95 F_max band
    return force


def test_augmentations_follow_the_datasets_rule():
    force = _ramp()
    # DATA_FORMATS.md, independently: i_start = first F >= 5 N, i_peak = first
    # F >= 0.975 F_max, linspace over [i_start, i_peak]; shift +k while F >= 0.95 F_max.
    i_start = int(np.argmax(force >= 5.0))
    i_peak = int(np.argmax(force >= 0.975 * force.max()))
    base = i_start + np.linspace(0, i_peak - i_start, 3).astype(int)
    got = augmented_indices(force)
    assert base[1] - base[0] >= 5  # (the published code caps the count at this gap)
    assert got[0] == tuple(base)
    assert got == [tuple(base + k) for k in range(5)]  # the hold keeps F at F_max
    dropped = augmented_indices(_ramp(hold_drop=i_peak + 3))
    assert dropped == [tuple(base + k) for k in range(3)]
    # The published code, as the generator reproduces it (no depth shift at constant depth):
    # same count, and for a hard object whose depth no longer grows, one augmentation.
    from tactile_compliance.synthetic.timeseries import select_frames

    depth = np.ones_like(force)
    for f in (force, _ramp(hold_drop=i_peak + 3), _ramp(rise=8), _ramp(rise=5, onset=3)):
        expected = select_frames(f, depth, depth, label_pa=1e4)
        assert len(augmented_indices(f, modulus_pa=1e4, max_depth_mm=[depth])) == expected.num_aug
        assert augmented_indices(f)[0] == tuple(expected.force)
    assert select_frames(force, depth, depth, label_pa=1e7).num_aug == 1
    assert len(augmented_indices(force, modulus_pa=1e7, max_depth_mm=[depth])) == 1
    with pytest.raises(ValueError, match=r"no frame selection: peak force 8\.0 N"):
        augmented_indices(np.r_[np.zeros(5), np.full(10, 8.0)])


# ---------------------------------------------------------------------- record
def test_record_writes_the_datasets_raw_layout(grasp, tmp_path):
    info = ObjectInfo(grasp["name"], grasp["modulus_pa"], "Rubber", "Sphere")
    readings = Readings.from_csv(grasp["readings"])
    out = tmp_path / "data"
    with open_source(f"video:{grasp['video']}") as source:
        first = record_grasp(source, readings, out, info)
    assert first.grasp == 0 and first.path == out / grasp["name"] / "grasp=0"
    frames = decoded(grasp["video"])[: first.n_frames]
    # Stopped on release (force < 0.5 F_max after the peak), not at the end of the video.
    assert first.n_frames < len(decoded(grasp["video"]))
    assert grasp["force"][first.n_frames - 1] < 0.5 * grasp["force"].max()
    indices = first.frame_indices
    assert indices == augmented_indices(
        grasp["force"][: first.n_frames],
        modulus_pa=info.modulus_pa,
        max_depth_mm=[reconstruct_depth(difference_images(frames, frames[0])).max(axis=(1, 2))],
    )
    diff = difference_images(frames, frames[0])  # no calibration: the first frame
    depth = reconstruct_depth(diff)
    expected_estimates = dataset_estimates_pa(
        grasp["force"][: first.n_frames], grasp["width"][: first.n_frames], depth
    )
    np.testing.assert_allclose(first.estimates_pa, expected_estimates, rtol=1e-9)
    for k, idx in enumerate(indices):
        sample = first.path / f"augmentation={k}"
        # An estimate whose fit failed has no file, as in the dataset (at 60 x 84 px the
        # dataset's constants, fitted to 350-px-wide frames, find no contact area).
        estimate_files = [
            name
            for name, value in zip(
                ("elastic_estimate.pkl", "hertz_estimate.pkl"), expected_estimates, strict=True
            )
            if np.isfinite(value)
        ]
        assert sorted(p.name for p in sample.iterdir()) == sorted(
            ["RGB.pkl", "depth.pkl", "forces.pkl", "widths.pkl", *estimate_files]
        )
        rgb = load_numpy_pickle(sample / "RGB.pkl")
        assert rgb.shape == (3, *REPLAY_SIZE, 3) and rgb.dtype == np.float32
        np.testing.assert_array_equal(rgb, diff[list(idx)])  # BGR, centred near 0.5
        assert abs(float(np.median(rgb)) - 0.5) < 0.02
        np.testing.assert_array_equal(load_numpy_pickle(sample / "depth.pkl"), depth[list(idx)])
        np.testing.assert_allclose(
            load_numpy_pickle(sample / "forces.pkl"), grasp["force"][list(idx)]
        )
        np.testing.assert_allclose(
            load_numpy_pickle(sample / "widths.pkl"), grasp["width"][list(idx)]
        )
        for name in estimate_files:
            assert load_numpy_pickle(sample / name).shape == ()
    meta = json.loads((out / grasp["name"] / "metadata.json").read_text())
    assert meta["youngs_modulus"] == grasp["modulus_pa"] and meta["material"] == "Rubber"

    # A second grasp gets the next number; the first is not touched.
    before = {p: p.read_bytes() for p in first.path.rglob("*.pkl")}
    with open_source(f"video:{grasp['video']}") as source:
        second = record_grasp(source, readings, out, info)
    assert second.grasp == 1
    assert {p: p.read_bytes() for p in first.path.rglob("*.pkl")} == before
    table = pd.read_csv(first.object_table)
    assert table.loc[0, "Label"] == grasp["name"] and table.loc[0, "Trials Recorded?"] == 2
    assert table.loc[0, "Modulus [Pa]"] == pytest.approx(grasp["modulus_pa"], rel=1e-6)
    assert not list((out / grasp["name"]).glob(".partial*"))

    # Another modulus for the same object writes nothing.
    wrong = ObjectInfo(grasp["name"], 2 * grasp["modulus_pa"])
    with (
        open_source(f"video:{grasp['video']}") as source,
        pytest.raises(ValueError, match="modulus"),
    ):
        record_grasp(source, readings, out, wrong)
    assert sorted(p.name for p in (out / grasp["name"]).iterdir()) == [
        "grasp=0",
        "grasp=1",
        "metadata.json",
    ]


def test_bad_frames_and_missing_readings_do_not_lose_the_recording(grasp, tmp_path):
    frames = decoded(grasp["video"])
    folder = tmp_path / "frames"
    folder.mkdir()
    times = np.arange(len(frames)) / REPLAY_FPS
    times[3] = times[1]  # frame 3 goes back in time
    for i, frame in enumerate(frames):
        if i == 5:
            frame = frame[:-4]  # frame 5 has the wrong size
        cv2.imwrite(str(folder / f"{i:04d}.png"), frame)
    (tmp_path / "times.csv").write_text(
        "timestamp_s\n" + "\n".join(map(repr, times.tolist())) + "\n"
    )
    readings = Readings.from_csv(grasp["readings"])
    # The robot's log starts late: the first two frames have no reading.
    late = Readings(readings.timestamp_s[2:], readings.force_n[2:], readings.width_m[2:])
    source = open_source(f"folder:{folder}", timestamps_csv=tmp_path / "times.csv")
    info = ObjectInfo(grasp["name"], grasp["modulus_pa"])
    result = record_grasp(source, late, tmp_path / "data", info)
    reasons = "\n".join(result.skipped)
    assert len(result.skipped) == 4, reasons
    assert reasons.count("no force/width reading") == 2
    assert "timestamps go backwards" in reasons and "the first frame was 60x84" in reasons
    assert (result.path / "augmentation=0" / "RGB.pkl").is_file()


def test_a_grasp_without_a_press_writes_nothing(grasp, tmp_path):
    readings = Readings([0.0, 100.0], [1.0, 1.0], [0.05, 0.05])  # never 5 N
    with (
        open_source(f"video:{grasp['video']}") as source,
        pytest.raises(ValueError, match="no frame selection"),
    ):
        record_grasp(source, readings, tmp_path / "data", ObjectInfo("thing", 1e5))
    assert not (tmp_path / "data").exists()


# ---------------------------------------------------------------------- end to end
def run_end_to_end(grasp, tmp_path, inputs, size, extend_sensor=None, sensor_units=None):
    """calibrate -> record -> import burgess -> predict, and live on the same video.

    ``extend_sensor(path)`` may change the calibration file before it is used; the
    checkpoint was trained on estimates in ``sensor_units`` (default the Wedge's)."""
    ckpt = top10nn_checkpoint(
        tmp_path / "m.pt", inputs=inputs, size=size, sensor_units=sensor_units
    )
    sensor, data, store = tmp_path / "sensor.json", tmp_path / "data", tmp_path / "store"
    common = ["--readings", grasp["readings"], "--calibration", sensor]
    cli("calibrate", f"video:{grasp['still']}", "--out", sensor, "--frames", 5)
    if extend_sensor is not None:
        extend_sensor(sensor)
    recorded = json.loads(
        cli(
            "record",
            f"video:{grasp['video']}",
            "--out",
            data,
            "--object",
            grasp["name"],
            "--modulus",
            grasp["modulus_pa"],
            *common,
            "--json",
        )
    )
    cli("import", "burgess", data, "--out", store, "--fingers", "markerless")
    predicted = json.loads(cli("predict", ckpt, store, "--json"))
    rows = {p["augmentation"]: p for p in predicted["predictions"]}
    assert len(rows) == recorded["augmentations"]
    events = json_lines(cli("live", ckpt, f"video:{grasp['video']}", *common, "--json"))
    # The toy model was trained on frames of another size: live says so once, first.
    warned = [e for e in events if e["event"] == "warning" and "px frames" in e["reason"]]
    assert len(warned) <= 1
    events = [e for e in events if e["event"] == "estimate"]
    final = [e for e in events if e["final"]]
    assert len(final) == 1 and events[-1] is final[0]
    assert final[0]["frame_indices"] == recorded["frame_indices"][0]
    assert final[0]["frames_seen"] == recorded["n_frames"]
    assert len(events) >= 3  # provisional estimates came first
    assert final[0]["log10_modulus_pa"] == pytest.approx(rows[0]["pred_log10_pa"], abs=1e-5)
    return events, rows


def test_record_import_predict_and_live_agree(grasp, tmp_path):
    events, rows = run_end_to_end(grasp, tmp_path, "ImageFW", (72, 72))
    # The agreement is no accident: other frames (the provisional selections) give other
    # values.
    final = events[-1]
    others = [e["log10_modulus_pa"] for e in events if e["frame_indices"] != final["frame_indices"]]
    assert others and all(abs(v - rows[0]["pred_log10_pa"]) > 1e-5 for v in others)
    assert format_live_event(events[-1]).startswith("final       E = ")


def test_live_with_several_checkpoints_gives_an_interval(grasp, tmp_path):
    """Each member streams the same frames; the final event combines the members' finals."""
    from tactile_compliance.inference.live import live_estimates, load_members
    from tactile_compliance.inference.streaming import predict_trajectory

    paths = [top10nn_checkpoint(tmp_path / f"m{seed}.pt", seed=seed) for seed in (0, 1)]
    members = load_members(paths)
    readings = Readings.from_csv(grasp["readings"])
    with open_source(f"video:{grasp['video']}") as source:
        events = list(live_estimates(members, source, readings, level=0.9))
    events = [e for e in events if e["event"] == "estimate"]  # not the frame-size warning
    final = events[-1]
    assert final["final"] and [e["final"] for e in events].count(True) == 1
    # Each member's final is its own whole-trajectory estimate on the same frames.
    frames = decoded(grasp["video"])[: final["frames_seen"]]
    force, width = grasp["force"][: len(frames)], grasp["width"][: len(frames)]
    for member, got in zip(members, final["members_log10"], strict=True):
        expected, _ = predict_trajectory(
            member, frames, force, width, frame_kind="raw", channel_order="BGR"
        )
        assert got == pytest.approx(expected.log10_modulus_pa, abs=1e-5)
    logs = final["members_log10"]
    assert final["log10_modulus_pa"] == pytest.approx(np.mean(logs), abs=1e-12)
    low, high = np.log10(final["interval_pa"])
    assert low < min(logs) <= max(logs) < high and final["level"] == 0.9
    assert "90% interval" in format_live_event(final)


def test_live_runs_an_exported_directory_with_a_window_in_seconds(grasp, tmp_path):
    """``live`` takes what ``export --safetensors`` writes, and ``--window-s`` is
    ``--window`` in time: n frames at a constant rate are (n - 1) / fps seconds."""
    ckpt = top10nn_checkpoint(tmp_path / "m.pt")
    exported = tmp_path / "model-dir"
    cli("export", ckpt, "--safetensors", exported)
    source = [f"video:{grasp['video']}", "--readings", grasp["readings"], "--json"]
    by_frames = json_lines(cli("live", ckpt, *source, "--window", 6))[-1]
    by_time = json_lines(cli("live", exported, *source, "--window-s", 5 / REPLAY_FPS))[-1]
    whole = json_lines(cli("live", exported, *source))[-1]
    assert by_frames["final"] and by_time["final"]
    assert by_time["frame_indices"] == by_frames["frame_indices"] != whole["frame_indices"]
    assert by_time["log10_modulus_pa"] == pytest.approx(by_frames["log10_modulus_pa"], abs=1e-5)
    both = runner.invoke(
        app, ["live", str(ckpt), *map(str, source), "--window", "6", "--window-s", "0.2"]
    )
    assert both.exit_code != 0 and "not both" in both.output


def test_live_differences_each_frame_once(grasp, tmp_path, monkeypatch):
    """One difference image per frame, shared by every member's stream (and, for ALL
    inputs, the depth map), not recomputed for each selection and member."""
    from tactile_compliance.inference import live, streaming

    differenced: list[int] = []
    frames_read: list[int] = []

    def counting(module):
        original = module.difference_images

        def wrapper(frames, reference):
            differenced.append(len(frames))
            return original(frames, reference)

        monkeypatch.setattr(module, "difference_images", wrapper)

    counting(live)
    counting(streaming)
    original_iter = live.iter_frames

    def counting_iter(source, on_error=None):
        for item in original_iter(source, on_error):
            frames_read.append(1)
            yield item

    monkeypatch.setattr(live, "iter_frames", counting_iter)
    paths = [top10nn_checkpoint(tmp_path / f"m{seed}.pt", seed=seed) for seed in (0, 1)]
    readings = Readings.from_csv(grasp["readings"])
    with open_source(f"video:{grasp['video']}") as source:
        events = list(live.live_estimates(live.load_members(paths), source, readings))
    assert len(events) >= 3 and events[-1]["final"]  # provisional selections, then the final
    assert len(frames_read) > 10 and sum(differenced) == len(frames_read)


def test_two_sensors_write_both_fingers(grasp, tmp_path):
    readings = Readings.from_csv(grasp["readings"])
    info = ObjectInfo(grasp["name"], grasp["modulus_pa"])
    with (
        open_source(f"video:{grasp['video']}") as left,
        open_source(f"video:{grasp['video']}") as right,
    ):
        result = record_grasp(left, readings, tmp_path / "data", info, markers_source=right)
    sample = result.path / "augmentation=0"
    rgb, markers = (load_numpy_pickle(sample / n) for n in ("RGB.pkl", "RGB_markers.pkl"))
    np.testing.assert_array_equal(rgb, markers)  # the same frames, paired in order
    expected = reconstruct_depth(markers, markers=True)  # marker pixels masked and filled
    np.testing.assert_allclose(load_numpy_pickle(sample / "depth_markers.pkl"), expected, atol=1e-6)
    from tactile_compliance.data.burgess import import_burgess

    report = import_burgess(tmp_path / "data", tmp_path / "store")
    assert report.samples_imported == 2 * len(result.frame_indices) and not report.problems


@pytest.mark.slow
def test_end_to_end_with_estimates_at_the_datasets_frame_size(tmp_path):
    """ALL inputs: the analytical estimates from depth maps agree too (250 x 350 frames,
    where the dataset's estimator constants apply)."""
    data = make_replay_grasp(tmp_path / "grasp", (250, 350))
    events, rows = run_end_to_end(data, tmp_path, "ALL", (72, 72))
    assert np.isfinite(rows[0]["pred_pa"]) and events[-1]["final"]


def _depth_model_for(reference, px_per_mm, seed=0):
    """A depth model fitted on ball presses rendered by the generator at the frame size."""
    from tactile_compliance.data.depth_model import BallPress, find_contact_circle, fit_depth_model
    from tactile_compliance.synthetic.render import render_frames, sample_sensor_look

    rng = np.random.default_rng(seed)
    look = sample_sensor_look(rng, markers=False)
    h, w = reference.shape[:2]
    rows, cols = np.mgrid[0:h, 0:w]
    ball_mm = 4.0
    presses = []
    own_reference = render_frames(np.zeros((1, h, w), np.float32), look, rng)[0]
    for k in range(6):
        x, y, d = rng.uniform(0.3 * w, 0.7 * w), rng.uniform(0.3 * h, 0.7 * h), 0.6
        rho2 = ((cols - x) ** 2 + (rows - y) ** 2) / px_per_mm**2
        cap = np.maximum(np.sqrt(np.maximum(ball_mm**2 - rho2, 0)) - (ball_mm - d), 0)
        frame = render_frames(cap[None].astype(np.float32), look, rng)
        diff = difference_images(frame, own_reference)[0]
        presses.append(BallPress(diff, find_contact_circle(diff), str(k)))
    return fit_depth_model(presses, ball_mm, px_per_mm, epochs=10)


def test_a_calibrated_sensor_gives_depth_and_estimates_in_its_units(grasp, tmp_path):
    """With a depth model and a pixel density in the calibration, `record` stores that
    model's depth maps and the estimates at that density, and `live` computes the same."""
    from tactile_compliance.acquisition.calibration import SensorCalibration
    from tactile_compliance.physics.dataset_estimates import DATASET_CONSTANTS
    from tactile_compliance.synthetic.render import pixel_size_mm

    px_per_mm = 1.0 / pixel_size_mm(REPLAY_SIZE)  # the renderer's density: 2.7 px/mm, not 16.40
    models = []

    def extend(path):
        base = SensorCalibration.load(path)
        model = _depth_model_for(base.reference, px_per_mm)
        models.append(model)
        SensorCalibration(base.geometry, base.reference, depth_model=model).save(path)

    units = {"depth_model": "calibrated", "px_per_mm": px_per_mm}
    events, rows = run_end_to_end(
        grasp, tmp_path, "ALL", (72, 72), extend_sensor=extend, sensor_units=units
    )
    assert np.isfinite(rows[0]["pred_pa"]) and events[-1]["final"]
    assert GraspStore.open(tmp_path / "store").sensor_units.to_dict() == units
    sample = tmp_path / "data" / grasp["name"] / "grasp=0"
    recorded = json.loads((tmp_path / "sensor.json").read_text())
    assert recorded["px_per_mm"] == pytest.approx(px_per_mm)
    sensor = SensorCalibration.load(tmp_path / "sensor.json")
    n_frames = events[-1]["frames_seen"]
    frames = decoded(grasp["video"])[:n_frames]
    depth = models[0].depth_mm(difference_images(frames, sensor.reference))
    idx = list(events[-1]["frame_indices"])
    np.testing.assert_array_equal(
        load_numpy_pickle(sample / "augmentation=0" / "depth.pkl"), depth[idx]
    )
    from dataclasses import replace

    expected = dataset_estimates_pa(
        grasp["force"][:n_frames],
        grasp["width"][:n_frames],
        depth,
        replace(DATASET_CONSTANTS, px_per_mm=px_per_mm),
    )
    stored = [
        float(load_numpy_pickle(sample / "augmentation=0" / name))
        for name in ("elastic_estimate.pkl", "hertz_estimate.pkl")
    ]
    np.testing.assert_allclose(stored, expected, rtol=1e-9)
    wedge = dataset_estimates_pa(grasp["force"][:n_frames], grasp["width"][:n_frames], depth)
    assert not np.allclose(stored, wedge, equal_nan=True)  # the density matters

    # Estimates in other units are refused, never mixed: a Wedge-trained ALL checkpoint on
    # this store or this sensor, and an uncalibrated grasp into this dataset.
    wedge_ckpt = top10nn_checkpoint(tmp_path / "wedge.pt", inputs="ALL")
    for args in (
        ["predict", wedge_ckpt, tmp_path / "store"],
        ["live", wedge_ckpt, f"video:{grasp['video']}",
         "--readings", grasp["readings"], "--calibration", tmp_path / "sensor.json"],
    ):  # fmt: skip
        result = runner.invoke(app, [str(a) for a in args])
        assert result.exit_code == 2 and "other units" in result.output, result.output
        assert len(result.output.strip().splitlines()) == 1  # one line, no estimate
    with (
        open_source(f"video:{grasp['video']}") as source,
        pytest.raises(ValueError, match=r"calibrated depth model at 2\.7"),
    ):
        record_grasp(
            source,
            Readings.from_csv(grasp["readings"]),
            tmp_path / "data",
            ObjectInfo(grasp["name"], grasp["modulus_pa"]),
        )
    assert sorted(p.name for p in sample.parent.iterdir()) == ["grasp=0", "metadata.json"]


def test_bad_sources_are_one_line_errors_in_the_cli(grasp, tmp_path):
    ckpt = top10nn_checkpoint(tmp_path / "m.pt")
    cases = {
        "no camera": ["live", ckpt, "camera:97", "--readings", grasp["readings"]],
        "no device": [
            "record",
            "mini:/dev/v4l/by-id/usb-none-video-index0",
            "--out",
            tmp_path / "d",
            "--object",
            "x",
            "--modulus",
            1e5,
            "--readings",
            grasp["readings"],
        ],
        "no press": [
            "live",
            ckpt,
            f"video:{grasp['still']}",
            "--readings",
            grasp["readings"],
        ],
    }
    for label, args in cases.items():
        result = runner.invoke(app, [str(a) for a in args])
        assert result.exit_code == 2, (label, result.output)
        errors = [line for line in result.output.splitlines() if line.startswith("error:")]
        assert len(errors) == 1, (label, result.output)
    assert not (tmp_path / "d").exists()


def test_the_documented_robot_loop_runs(grasp, tmp_path, monkeypatch):
    """docs/inference.md's GelSight Mini loop, with the camera replaced by the replayed video
    and the gripper by the readings; it prints provisional estimates and the final one."""
    from pathlib import Path

    from tactile_compliance.acquisition.calibration import calibrate

    text = (Path(__file__).resolve().parents[1] / "docs" / "inference.md").read_text()
    block = text.split("### A robot loop with a GelSight Mini")[1]
    block = block.split("```python\n", 1)[1].split("```", 1)[0]
    assert "mini:/dev/v4l/by-id/" in block and "runs/RUN/best.pt" in block
    block = block.replace("mini:/dev/v4l/by-id/usb-GelSight_GelSight_Mini-video-index0", "MINI")
    block = block.replace('"MINI"', repr(f"video:{grasp['video']}"))
    monkeypatch.chdir(tmp_path)
    top10nn_checkpoint(tmp_path / "m.pt")
    block = block.replace("runs/RUN/best.pt", "m.pt")
    calibrate(f"video:{grasp['still']}", n_frames=5, out="sensor.json")
    readings = pd.read_csv(grasp["readings"])

    class Gripper:  # replays the readings, one per frame
        def __init__(self):
            self.i, self.released = -1, False

        def close(self, **_):
            pass

        def force_n(self):
            self.i += 1
            return float(readings.force_n[self.i])

        def width_m(self):
            return float(readings.width_m[self.i])

        def opening(self):
            return self.released

        def open(self):
            self.released = True

    printed: list[str] = []
    namespace = {"gripper": Gripper(), "print": lambda *a: printed.append(" ".join(map(str, a)))}
    exec(compile(block, "docs/inference.md", "exec"), namespace)
    assert namespace["final"] is not None and namespace["final"].final
    assert printed[-1].endswith("(final)") and len(printed) >= 3


def test_readings_are_followed_while_the_robot_writes_them(tmp_path):
    from tactile_compliance.acquisition.readings import FollowedReadings

    path = tmp_path / "log.csv"
    follow = FollowedReadings(path, wait_s=0.05)  # the file does not exist yet
    with pytest.raises(ReadingError, match="last reading: none yet"):
        follow(0.0)
    path.write_text("timestamp_s,force_n,width_m\n0.0,0.0,0.05\n0.1,10.0,0.049\n0.2,20")
    assert follow(0.05) == pytest.approx((5.0, 0.0495))  # the incomplete line is ignored
    with pytest.raises(ReadingError, match=r"last reading: 0\.1000 s"):
        follow(0.15)
    with open(path, "a") as handle:  # the robot finishes the line and goes on
        handle.write(",0.048\n0.3,30.0,0.047\n")
    assert follow(0.25) == pytest.approx((25.0, 0.0475))
    path.write_text("timestamp_s,force_n,width_m\n0.0,x,0.05\n0.1,1,0.05\n")
    with pytest.raises(ValueError, match="row 1 holds a value that is not a number"):
        FollowedReadings(path)


def test_a_slow_estimator_on_a_live_sensor_pairs_every_frame_with_its_force(grasp, tmp_path):
    """A model slower than the frame period (0.2 s per estimate against 67 ms per frame)
    still gets each frame stamped on arrival: the final estimate is the replay's."""
    from tactile_compliance.inference.live import live_estimates, load_members

    ckpt = top10nn_checkpoint(tmp_path / "m.pt", inputs="ImageFW")
    readings = Readings.from_csv(grasp["readings"])
    with open_source(f"video:{grasp['video']}") as replay:
        replayed = list(live_estimates(load_members([ckpt]), replay, readings))
    slow = load_members([ckpt])
    original = slow[0].predict

    def sluggish(*args, **kwargs):
        time.sleep(0.2)
        return original(*args, **kwargs)

    slow[0].predict = sluggish
    with ArraySource(
        decoded(grasp["video"]), fps=REPLAY_FPS, live=True, name="paced video"
    ) as camera:
        lived = list(live_estimates(slow, camera, readings))
    final, expected = lived[-1], replayed[-1]
    assert final["final"] and expected["final"]
    assert final["frame_indices"] == expected["frame_indices"]
    assert final["log10_modulus_pa"] == pytest.approx(expected["log10_modulus_pa"], abs=0.01)
    # Behind the sensor, the loop skipped provisional estimates instead of frames.
    assert final["frames_seen"] == expected["frames_seen"]
    assert len(lived) < len(replayed)


def test_a_grasp_without_estimates_warns_which_models_it_cannot_serve(grasp, tmp_path):
    """At 60 x 84 px and the Wedge's 16.40 px/mm the dataset's estimator finds too little
    contact area: the grasp is written, and `record` says at once that ALL models will
    skip it (before, `predict` only counted 'Skipped 4 samples')."""
    info = ObjectInfo(grasp["name"], grasp["modulus_pa"])
    with open_source(f"video:{grasp['video']}") as source:
        result = record_grasp(source, Readings.from_csv(grasp["readings"]), tmp_path / "d", info)
    assert not np.isfinite(result.estimates_pa).any()
    assert any("ALL models will skip it" in w for w in result.warnings)
    assert "Warning     no elastic or Hertz analytical estimate" in result.format()


def test_live_without_an_estimate_names_the_real_cause(grasp, tmp_path):
    """One line, exit 2, and the cause: estimates that cannot be computed (an ALL model at
    60 x 84 px, where an ImageFW model selects frames), readings on another clock, a
    grasp too weak for the selection."""
    all_ckpt = top10nn_checkpoint(tmp_path / "all.pt", inputs="ALL")
    fw_ckpt = top10nn_checkpoint(tmp_path / "fw.pt", inputs="ImageFW")
    video = f"video:{grasp['video']}"
    weak = write_readings_csv(
        tmp_path / "weak.csv",
        np.arange(len(grasp["force"])) / REPLAY_FPS,
        np.asarray(grasp["force"]) * 0.1,
        grasp["width"],
    )
    cases = [
        (
            all_ckpt,
            grasp["readings"],
            [],
            "analytical estimates (ALL, FWE, DepthALL, FWR inputs) could not be",
        ),
        (fw_ckpt, grasp["readings"], ["--readings-offset-s", "100"], "--readings-offset-s"),
        (fw_ckpt, weak, [], "never reached the frame selection"),
    ]
    for ckpt, readings, extra, cause in cases:
        result = runner.invoke(
            app, [str(a) for a in ["live", ckpt, video, "--readings", readings, *extra]]
        )
        assert result.exit_code == 2, result.output
        errors = [line for line in result.output.splitlines() if line.startswith("error:")]
        assert len(errors) == 1 and cause in errors[0], result.output
    ok = runner.invoke(app, ["live", str(fw_ckpt), video, "--readings", str(grasp["readings"])])
    assert ok.exit_code == 0 and "final" in ok.output
