"""Grasps from ROS 2 bags (``rosbag:PATH``): bags written with rosbags' own Writer
(rosbag2, sqlite3) from a synthetic grasp video and, when the reference data is present,
from the 15 real Wedge recordings, read by ``record``, ``estimate``, ``predict`` and
``live``, against the video + readings CSV path.

Tolerance of "the bag gives the video's estimates": 1e-9 relative on the synthetic
grasp, 1e-7 on the real ones (2.5e-9 seen). The bag holds the video's decoded frames
losslessly (bgr8, or PNG) at the video's own frame times, and the readings at the CSV's
times; only the stamps' whole nanoseconds differ from the float seconds, which moves an
interpolated reading by about 1e-9 of itself.
"""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from helpers import (
    WEDGE_CORNERS,
    cli,
    json_lines,
    make_replay_grasp,
    runner,
    top10nn_checkpoint,
    write_bag,
)
from tactile_compliance.acquisition.sensors import SensorError, VideoCaptureSource, open_source
from tactile_compliance.cli import app

pytest.importorskip("rosbags")

SIZE = (250, 350)


def video_frames(video):
    """The video's frames and times as the ``video:`` / ``wedge:`` sources read them."""
    with VideoCaptureSource(video) as source:
        times, frames = zip(*source, strict=True)
    return np.stack(frames), np.array(times)


def bag_of(video, readings_csv, path, **options):
    frames, times = video_frames(video)
    table = pd.read_csv(readings_csv)
    return write_bag(path, frames, times, table.timestamp_s.to_numpy(),
                     table.force_n.to_numpy(), table.width_m.to_numpy(), **options)  # fmt: skip


@pytest.fixture(scope="module")
def grasp(tmp_path_factory):

    return make_replay_grasp(tmp_path_factory.mktemp("bag-grasp"), SIZE)


@pytest.fixture(scope="module")
def bag(grasp):
    return bag_of(grasp["video"], grasp["readings"], grasp["root"] / "grasp_bag")


# ---------------------------------------------------------------------- synthetic
def test_a_bag_gives_the_frames_and_readings_of_the_video_and_csv(grasp, bag):
    frames, times = video_frames(grasp["video"])
    with open_source(f"rosbag:{bag}") as source:
        got = list(source)
        t, force, width = source.readings_arrays
    assert len(got) == len(frames)
    assert all(np.array_equal(f, g) for f, (_, g) in zip(frames, got, strict=True))
    # Seconds since the bag's first message (the earliest stamp here: t = 0).
    np.testing.assert_allclose([g[0] for g in got], times, atol=1e-9)
    table = pd.read_csv(grasp["readings"])
    np.testing.assert_allclose(t, table.timestamp_s, atol=1e-9)
    np.testing.assert_allclose(force, table.force_n, rtol=1e-12)
    np.testing.assert_allclose(width, table.width_m, rtol=1e-12)


@pytest.mark.parametrize("image", ["raw", "png"])
def test_estimate_and_record_read_a_bag_as_the_video_and_csv(grasp, tmp_path, image):
    bag = bag_of(grasp["video"], grasp["readings"], tmp_path / "bag", image=image)
    by_video = json.loads(
        cli("estimate", f"video:{grasp['video']}", "--readings", grasp["readings"], "--json")
    )
    by_bag = json.loads(cli("estimate", f"rosbag:{bag}", "--json"))
    assert all(v is not None for v in by_video["estimates_pa"])
    assert by_bag["estimates_pa"] == pytest.approx(by_video["estimates_pa"], rel=1e-9)
    assert by_bag["frame_indices"] == by_video["frame_indices"]
    recorded = json.loads(
        cli(
            "record",
            f"rosbag:{bag}",
            "--out",
            tmp_path / "data",
            "--object",
            "thing",
            "--modulus",
            grasp["modulus_pa"],
            "--json",
        )
    )
    assert recorded["estimates_pa"] == pytest.approx(by_video["estimates_pa"], rel=1e-9)


def test_live_and_predict_read_a_bag(grasp, bag, tmp_path):

    ckpt = top10nn_checkpoint(tmp_path / "m.pt", inputs="ALL", size=(72, 72))
    video = ["video:" + str(grasp["video"]), "--readings", grasp["readings"]]
    by_video = json_lines(cli("live", ckpt, *video, "--json"))
    by_bag = json_lines(cli("live", ckpt, f"rosbag:{bag}", "--json"))
    final_video, final_bag = by_video[-1], by_bag[-1]
    assert final_video["final"] and final_bag["final"]
    assert final_bag["log10_modulus_pa"] == pytest.approx(final_video["log10_modulus_pa"], abs=1e-6)
    assert final_bag["frame_indices"] == final_video["frame_indices"]
    shown = cli("predict", ckpt, f"rosbag:{bag}", "--json")  # stderr's warnings first
    assert "trained on 72x72 px frames" in shown  # once, before the JSON
    predicted = json.loads(shown[shown.index("{") :])
    assert predicted["final"] and predicted["source"] == f"rosbag {bag}"
    assert predicted["log10_modulus_pa"] == pytest.approx(final_bag["log10_modulus_pa"], abs=1e-6)
    assert "Pa" in cli("predict", ckpt, f"rosbag:{bag}")
    analytical = json.loads(cli("live", f"rosbag:{bag}", "--json").splitlines()[-1])
    estimated = json.loads(cli("estimate", f"rosbag:{bag}", "--json"))
    assert analytical["estimates_pa"] == pytest.approx(estimated["estimates_pa"], rel=1e-9)


def test_topics_axis_joints_and_stamps_are_options(grasp, tmp_path):
    frames, times = video_frames(grasp["video"])
    table = pd.read_csv(grasp["readings"])
    t, f, w = (table[c].to_numpy() for c in ("timestamp_s", "force_n", "width_m"))
    coarse = t[::3]  # the joint states at a third of the force's rate: interpolated
    bag = write_bag(tmp_path / "bag", frames, times, t, f, w, force_sign=-1.0,
                    extra_topics=["/other/image"], width_times_s=coarse)  # fmt: skip
    with pytest.raises(ValueError, match=r"2 sensor_msgs/Image or .* name the image topic"):
        open_source(f"rosbag:{bag}")
    joints = "joints=panda_finger_joint1+panda_finger_joint2"
    spec = f"rosbag:{bag},image=/gelsight/image_raw,axis=-z,{joints}"
    with open_source(spec) as source:
        bt, bf, bw = source.readings_arrays
    inside = t <= coarse[-1]  # force after the last joint state: left out
    np.testing.assert_allclose(bt, t[inside], atol=1e-9)
    np.testing.assert_allclose(bf, f[inside], rtol=1e-12)
    # Interpolated at stamps rounded to whole ns: 1e-9 of the width.
    np.testing.assert_allclose(bw, np.interp(t[inside], coarse, w[::3]), rtol=1e-8)
    with open_source(spec.replace("axis=-z", "axis=norm")) as source:
        norm = source.readings_arrays[1]
    np.testing.assert_allclose(norm, np.sqrt(f[inside] ** 2 + 0.05), rtol=1e-12)
    with open_source(f"{spec},stamps=bag") as source:  # logged at the stamps here
        np.testing.assert_allclose(source.readings_arrays[0], bt)
    for bad, cause in (
        (f"rosbag:{bag},image=/nope", "no topic '/nope'"),
        (f"rosbag:{bag},image=/ft/wrench", "holds geometry_msgs/msg/WrenchStamped"),
        (f"rosbag:{bag},axis=q", "force axis 'q'"),
        (f"rosbag:{bag},colour=red", "rosbag option 'colour=red'"),
        (f"rosbag:{bag},image=/gelsight/image_raw,joints=j7", "joint(s) ['j7'] not in"),
    ):
        with pytest.raises(ValueError, match=re.escape(cause)):
            open_source(bad)
    with pytest.raises(SensorError, match="no such bag"):
        open_source(f"rosbag:{tmp_path / 'missing'}")


def test_the_cli_says_what_is_wrong_with_a_bag(grasp, bag, tmp_path):
    result = runner.invoke(app, ["estimate", f"rosbag:{bag}", "--readings", str(grasp["readings"])])
    assert result.exit_code == 2 and "carries its own force and width" in result.output
    result = runner.invoke(app, ["estimate", f"rosbag:{bag},axis=-z"])
    assert result.exit_code == 2 and "no frame selection" in result.output, result.output


def test_a_missing_rosbags_says_how_to_install_it(monkeypatch, bag):
    import sys

    monkeypatch.setitem(sys.modules, "rosbags.highlevel", None)
    with pytest.raises(SensorError, match=r"pip install 'tactile-compliance\[ros\]'"):
        open_source(f"rosbag:{bag}")


# ---------------------------------------------------------------------- real data
def test_the_real_wedge_grasps_from_bags_give_the_video_estimates(reference_data_dir, tmp_path):
    """The first recording of each of the 5 real objects: ``calibrate`` + ``estimate`` on
    ``wedge:VIDEO`` and on a bag of its raw camera frames (bgr8, 640 x 480) give the same
    estimates. (A bag takes the same path for every grasp; the objects differ in contact
    size and force profile. All 15 took 38 s, a third of that is enough.)"""
    session = reference_data_dir / "real" / "wedge-grasps" / "2023-12-06"
    if not session.is_dir():
        pytest.skip(f"{session} is not present")
    geometry = ["--corners", WEDGE_CORNERS, "--warp-size", "300x400", "--frames", 3]
    videos = sorted(session.glob("*.avi"))
    assert len(videos) == 15
    first_of_each = [video for video in videos if video.stem.endswith("_1")]
    assert len(first_of_each) == 5
    for video in first_of_each:
        readings = video.with_name(f"{video.stem}_readings.csv")
        bag = bag_of(video, readings, tmp_path / f"{video.stem}_bag")
        cli("calibrate", f"wedge:{video}", "--out", tmp_path / "v.json", *geometry)
        # A bag's frames take no preset: the Wedge's crop is given as calibrate's option.
        cli("calibrate", f"rosbag:{bag}", "--out", tmp_path / "b.json", *geometry, "--crop-px", 25)
        by_video = json.loads(cli("estimate", f"wedge:{video}", "--readings", readings,
                                   "--calibration", tmp_path / "v.json", "--json"))  # fmt: skip
        by_bag = json.loads(
            cli("estimate", f"rosbag:{bag}", "--calibration", tmp_path / "b.json", "--json")
        )
        assert by_bag["estimates_pa"] == pytest.approx(by_video["estimates_pa"], rel=1e-7), video
        assert by_bag["frame_indices"] == by_video["frame_indices"], video
        for path in (bag, tmp_path / "v.json", tmp_path / "b.json"):
            shutil.rmtree(path) if Path(path).is_dir() else Path(path).unlink()
