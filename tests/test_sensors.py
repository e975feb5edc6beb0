"""Live frame sources and sensor calibration: geometry, timing, specs and the bad-source errors.

Videos and frames are made here with OpenCV, a few small frames each.
"""

from __future__ import annotations

import json
import sys
from typing import ClassVar

import cv2
import numpy as np
import pytest

from helpers import write_bag, write_video
from tactile_compliance.acquisition import sensors
from tactile_compliance.acquisition.calibration import SensorCalibration, calibrate
from tactile_compliance.acquisition.sensors import (
    MINI_GEOMETRY,
    WEDGE_GEOMETRY,
    DigitSource,
    FolderSource,
    FrameError,
    FrameGeometry,
    FrameSizeError,
    FrameSource,
    SensorError,
    TimestampError,
    VideoCaptureSource,
    iter_frames,
    open_source,
)
from tactile_compliance.outputs import OutputExistsError

SIZE = (48, 64)  # (H, W)


def _frames(n: int, size=SIZE, seed: int = 0) -> np.ndarray:
    """Frames that differ from each other (a moving bright square on a gradient)."""
    rng = np.random.default_rng(seed)
    h, w = size
    base = np.zeros((h, w, 3), np.uint8)
    base[..., 0] = np.linspace(60, 120, w, dtype=np.uint8)[None]
    base[..., 1] = np.linspace(80, 140, h, dtype=np.uint8)[:, None]
    base[..., 2] = 100
    out = np.repeat(base[None], n, axis=0)
    for i in range(n):
        out[i, 5 + i : 15 + i, 10 + i : 20 + i] = 220
    return np.clip(out.astype(int) + rng.integers(-2, 3, out.shape), 0, 255).astype(np.uint8)


# ---------------------------------------------------------------------- geometry
def test_geometry_warps_crops_and_resizes_as_documented():
    frame = _frames(1, (480, 640))[0]
    # The Wedge rig: 640 x 480 -> warp 400 x 300 -> 25 px per side -> 350 x 250.
    assert WEDGE_GEOMETRY.apply(frame).shape == (250, 350, 3)
    # Corners that pick the top-left quarter: the warp maps it onto the whole 300 x 400.
    quarter = FrameGeometry(
        warp_corners=((0, 0), (319, 0), (319, 239), (0, 239)), warp_size=(240, 320)
    )
    np.testing.assert_allclose(
        quarter.apply(frame).astype(float), frame[:240, :320].astype(float), atol=1
    )
    # The Mini: 1/7 per side, then 320 x 240 (W x H).
    mini = MINI_GEOMETRY.apply(_frames(1, (2464 // 8, 3280 // 8))[0])
    assert mini.shape == (240, 320, 3) and mini.dtype == np.uint8
    crop = FrameGeometry(crop_px=4, crop_fraction=0.25)
    out = crop.apply(frame[:48, :64])
    # 48 - 8 = 40 rows, 10 off each side -> 20; 64 - 8 = 56 columns, 14 off -> 28.
    assert out.shape == (20, 28, 3)
    np.testing.assert_array_equal(out, frame[14:34, 18:46])
    # A geometry survives its JSON form.
    assert FrameGeometry.from_dict(WEDGE_GEOMETRY.to_dict()) == WEDGE_GEOMETRY
    with pytest.raises(ValueError, match="together"):
        FrameGeometry(warp_size=(10, 10))
    with pytest.raises(FrameSizeError, match="expects 480x640"):
        WEDGE_GEOMETRY.apply(frame[:100, :100])


# ---------------------------------------------------------------------- video files
@pytest.mark.parametrize("fps", [18.0, 25.0, 30.0])
def test_a_video_replays_with_its_own_frame_times(tmp_path, fps):
    frames = _frames(6)
    write_video(tmp_path / "v.avi", frames, fps)
    with open_source(f"video:{tmp_path / 'v.avi'}") as source:
        got = list(source)
    times = np.array([t for t, _ in got])
    np.testing.assert_allclose(times, np.arange(6) / fps, atol=1e-6)
    assert all(f.shape == (*SIZE, 3) and f.dtype == np.uint8 for _, f in got)
    # MJPG is lossy: the decoded frames are close to what was written, not equal.
    assert np.abs(got[3][1].astype(int) - frames[3].astype(int)).mean() < 4


def test_specs_pick_the_presets(tmp_path):
    write_video(tmp_path / "v.avi", _frames(2, (96, 128)), 25)
    with open_source(f"mini:{tmp_path / 'v.avi'}") as source:
        assert isinstance(source, FrameSource)
        assert source.read()[1].shape == (240, 320, 3)  # the Mini's crop and resize
    with open_source(str(tmp_path / "v.avi")) as source:  # a plain path: as recorded
        assert source.read()[1].shape == (96, 128, 3)
    custom = FrameGeometry(output_size=(24, 32))
    with open_source(f"video:{tmp_path / 'v.avi'}", geometry=custom) as source:
        assert source.read()[1].shape == (24, 32, 3)


# ---------------------------------------------------------------------- bad sources
@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("camera:97", "cannot open the camera"),
        ("97", "cannot open the camera"),
        ("mini:/dev/v4l/by-id/usb-no-such-gelsight-video-index0", "no such device"),
        ("video:does-not-exist.avi", "no such video file"),
        ("folder:does-not-exist", "no such folder"),
    ],
)
def test_a_source_that_is_not_there_is_one_clear_error(spec, message):
    with pytest.raises(SensorError, match=message) as err:
        open_source(spec)
    assert isinstance(err.value, OSError) and "\n" not in str(err.value)


def test_bad_specs_are_value_errors():
    with pytest.raises(ValueError, match="unknown source kind 'webcam'"):
        open_source("webcam:0")
    with pytest.raises(ValueError, match="names no device"):
        open_source("mini:")


def test_digit_without_digit_interface_is_a_clear_error(monkeypatch):
    # None in sys.modules makes the import fail even where the package is installed.
    monkeypatch.setitem(sys.modules, "digit_interface", None)
    with pytest.raises(SensorError, match=r"pip install digit-interface.*non-commercial"):
        DigitSource("D12345")
    with pytest.raises(SensorError, match="digit-interface"):
        open_source("digit:D12345")


def _folder(tmp_path, sizes, times=None):
    folder = tmp_path / "frames"
    folder.mkdir()
    names = []
    for i, size in enumerate(sizes):
        name = f"f{i:03d}.png"
        cv2.imwrite(str(folder / name), _frames(1, size, seed=i)[0])
        names.append(name)
    if times is not None:
        rows = ["file,timestamp_s", *(f"{n},{t}" for n, t in zip(names, times, strict=True))]
        (tmp_path / "times.csv").write_text("\n".join(rows) + "\n")
    return folder


def test_a_frame_of_the_wrong_size_is_skipped_not_fatal(tmp_path):
    folder = _folder(tmp_path, [SIZE, SIZE, (40, 64), SIZE])
    source = FolderSource(folder, fps=10)
    errors: list[FrameError] = []
    got = list(iter_frames(source, errors.append))
    assert [round(t, 6) for t, _ in got] == [0.0, 0.1, 0.3]  # frame 2 left out, 3 kept
    assert len(errors) == 1 and isinstance(errors[0], FrameSizeError)
    assert "frame 2 is 40x64 px, the first frame was 48x64" in str(errors[0])
    # Plain iteration stops at the bad frame with the error.
    with pytest.raises(FrameSizeError), FolderSource(folder, fps=10) as again:
        list(again)


def test_timestamps_going_backwards_are_refused_per_frame(tmp_path):
    folder = _folder(tmp_path, [SIZE] * 4, times=[0.0, 0.1, 0.05, 0.2])
    source = FolderSource(folder, timestamps_csv=tmp_path / "times.csv")
    errors: list[FrameError] = []
    got = list(iter_frames(source, errors.append))
    assert [t for t, _ in got] == [0.0, 0.1, 0.2]
    assert len(errors) == 1 and isinstance(errors[0], TimestampError)
    assert "older than the previous frame" in str(errors[0])


def test_a_folder_needs_its_timing(tmp_path):
    folder = _folder(tmp_path, [SIZE])
    with pytest.raises(ValueError, match="fps or a timestamps CSV"):
        FolderSource(folder)


# ---------------------------------------------------------------------- calibration
def test_calibration_records_the_median_reference_and_round_trips(tmp_path):
    still = _frames(1)[0]
    rng = np.random.default_rng(1)
    frames = np.clip(still.astype(int) + rng.integers(-3, 4, (7, *still.shape)), 0, 255)
    frames[3] = 255  # one flash: the median ignores it
    folder = tmp_path / "still"
    folder.mkdir()
    for i, frame in enumerate(frames.astype(np.uint8)):
        cv2.imwrite(str(folder / f"{i}.png"), frame)
    geometry = FrameGeometry(crop_px=2)
    out = tmp_path / "sensor.json"
    calibration = calibrate(f"folder:{folder}", geometry=geometry, n_frames=7, out=out, fps=30)
    expected = np.median(frames[:, 2:-2, 2:-2], axis=0).round().astype(np.uint8)
    np.testing.assert_array_equal(calibration.reference, expected)
    # The camera size is recorded, so another camera size is refused later.
    assert calibration.geometry.input_size == SIZE and calibration.geometry.crop_px == 2
    loaded = SensorCalibration.load(out)
    np.testing.assert_array_equal(loaded.reference, calibration.reference)  # PNG: lossless
    assert loaded.geometry == calibration.geometry and loaded.n_frames == 7
    # Sources opened with it apply its geometry and check the camera size.
    write_video(tmp_path / "other.avi", _frames(2, (40, 40)), 25)
    with (
        loaded.open(f"video:{tmp_path / 'other.avi'}") as source,
        pytest.raises(FrameSizeError, match="expects 48x64"),
    ):
        source.read()
    # Re-running replaces its own file, never another file.
    calibrate(f"folder:{folder}", n_frames=2, out=out, fps=30)
    other = tmp_path / "notes.json"
    other.write_text('{"mine": 1}')
    with pytest.raises(OutputExistsError):
        calibrate(f"folder:{folder}", n_frames=2, out=other, fps=30)
    assert other.read_text() == '{"mine": 1}'
    with pytest.raises(ValueError, match="not a sensor calibration"):
        SensorCalibration.load(other)


def test_calibrate_json_describes_what_it_wrote(tmp_path):
    from typer.testing import CliRunner

    from tactile_compliance.cli import app

    write_video(tmp_path / "v.avi", _frames(3, (96, 128)), 25)
    out = tmp_path / "sensor.json"
    args = ["calibrate", f"video:{tmp_path / 'v.avi'}", "--out", str(out), "--frames", "3"]
    result = CliRunner().invoke(app, [*args, "--json"])
    assert result.exit_code == 0, result.output
    shown = json.loads(result.stdout)
    written = json.loads(out.read_text())
    assert shown.pop("out") == str(out) and "reference_png_base64" not in shown
    assert shown == {k: v for k, v in written.items() if k != "reference_png_base64"}


def test_calibration_needs_enough_frames(tmp_path):
    write_video(tmp_path / "v.avi", _frames(3), 25)
    with pytest.raises(SensorError, match="only 3 of 10 frames"):
        calibrate(f"video:{tmp_path / 'v.avi'}", n_frames=10)


def test_video_capture_source_reports_a_device_that_stops(tmp_path):
    write_video(tmp_path / "v.avi", _frames(2), 25)
    # A file read as a live device: the end of the file is a device that stopped.
    source = VideoCaptureSource(tmp_path / "v.avi", timestamps="clock")
    source.is_file = False
    list(zip(range(2), source, strict=False))
    with pytest.raises(SensorError, match="stopped delivering"):
        source.read()
    source.close()


def test_calibrate_command_replaces_the_presets_steps(tmp_path):
    from typer.testing import CliRunner

    from tactile_compliance.cli import app

    write_video(tmp_path / "v.avi", _frames(3, (96, 128)), 25)
    runner = CliRunner()
    out = tmp_path / "sensor.json"
    corners = "0,0 127,0 127,95 0,95"
    args = ["calibrate", f"mini:{tmp_path / 'v.avi'}", "--out", str(out), "--frames", "3"]
    result = runner.invoke(
        app,
        [*args, "--corners", corners, "--warp-size", "48x64", "--crop-px", "4", "--size", "20x28"],
    )
    assert result.exit_code == 0, result.output
    assert "20x28 px frames" in result.output
    geometry = SensorCalibration.load(out).geometry
    assert geometry.warp_size == (48, 64) and geometry.crop_px == 4
    assert geometry.crop_fraction == pytest.approx(1 / 7)  # kept from the Mini preset
    assert geometry.input_size == (96, 128) and geometry.output_size == (20, 28)
    bad = runner.invoke(app, [*args, "--corners", "1,2 3,4"])
    assert bad.exit_code == 2 and "four points" in bad.output


# ---------------------------------------------------------------------- the contract
# Every kind of source the table lists runs through the same checks, opened by its spec
# as `live`, `record` and `calibrate` open it. Hardware is faked at the driver
# (cv2.VideoCapture, digit_interface); replays read files written here.
SCENE_BGR = (200, 110, 30)  # blue high, red low: a red-blue swap shows
CONTRACT_FRAMES = 4


def _scene(size):
    frame = np.empty((*size, 3), np.uint8)
    frame[:] = SCENE_BGR
    frame[: size[0] // 4, : size[1] // 4] = 240  # some structure for the codec
    return frame


class FakeCapture:
    """A cv2.VideoCapture of a camera or stream: ``frames`` BGR frames of ``size``, then
    nothing; ``mode`` is the (W, H) px it reports."""

    def __init__(self, size, mode=None, frames=CONTRACT_FRAMES + 50):
        self.size, self.mode, self.left, self.released = size, mode, frames, 0

    def isOpened(self):  # noqa: N802 - OpenCV's name
        return True

    def set(self, prop, value):
        return True

    def get(self, prop):
        mode = self.mode or (self.size[1], self.size[0])
        return {cv2.CAP_PROP_FRAME_WIDTH: mode[0], cv2.CAP_PROP_FRAME_HEIGHT: mode[1]}.get(
            prop, 0.0
        )

    def read(self):
        if self.left <= 0:
            return False, None
        self.left -= 1
        return True, _scene(self.size)

    def release(self):
        self.released += 1


def _fake_capture(monkeypatch, size, mode=None):
    monkeypatch.setattr(sensors.cv2, "VideoCapture", lambda target: FakeCapture(size, mode))


def _v4l_names(monkeypatch, tmp_path, **names):
    for node, name in names.items():
        (tmp_path / "v4l" / node).mkdir(parents=True)
        (tmp_path / "v4l" / node / "name").write_text(name + "\n")
    monkeypatch.setattr(sensors, "V4L_SYSFS", tmp_path / "v4l")


class FakeDigit:
    STREAMS: ClassVar[dict] = {}

    def __init__(self, serial):
        self.serial = serial

    def connect(self):
        pass

    def get_frame(self):  # digit-interface reads its camera with OpenCV: BGR
        return _scene((240, 320))

    def disconnect(self):
        pass


def _video(tmp_path, size):
    path = tmp_path / "replay.avi"
    write_video(path, np.stack([_scene(size)] * CONTRACT_FRAMES), 30.0)
    return path


def _open_mini_device(monkeypatch, tmp_path):
    _v4l_names(monkeypatch, tmp_path, video0="GelSight Mini R0B 2BG8-XYZ")
    _fake_capture(monkeypatch, (308, 410), mode=(3280, 2464))
    return "mini:0"


def _open_folder(monkeypatch, tmp_path):
    folder = tmp_path / "frames"
    folder.mkdir()
    for i in range(CONTRACT_FRAMES):
        cv2.imwrite(str(folder / f"{i:03d}.png"), _scene(SIZE))
    return f"folder:{folder}"


def _open_rosbag(monkeypatch, tmp_path):
    pytest.importorskip("rosbags")
    times = np.arange(CONTRACT_FRAMES) / 30.0
    frames = np.stack([_scene(SIZE)] * CONTRACT_FRAMES)
    force = np.linspace(0, 20, CONTRACT_FRAMES)
    write_bag(tmp_path / "bag", frames, times, times, force, np.full(CONTRACT_FRAMES, 0.05))
    return f"rosbag:{tmp_path / 'bag'}"


def _open_digit(monkeypatch, tmp_path):
    module = type(sys)("digit_interface")
    module.Digit = FakeDigit
    monkeypatch.setitem(sys.modules, "digit_interface", module)
    return "digit:D12345"


def _open_camera(monkeypatch, tmp_path):
    _fake_capture(monkeypatch, SIZE)
    return "camera:0"


def _open_wedge_stream(monkeypatch, tmp_path):
    _fake_capture(monkeypatch, (480, 640))
    return "wedge:http://rig:8080/stream.mjpg"


#: spec (made by the function) per case, and whether that source is live.
CONTRACT_CASES = {
    "mini-device": (_open_mini_device, True),
    "mini-replay": (lambda mp, tmp: f"mini:{_video(tmp, (96, 128))}", False),
    "wedge-stream": (_open_wedge_stream, True),
    "wedge-replay": (lambda mp, tmp: f"wedge:{_video(tmp, (480, 640))}", False),
    "digit": (_open_digit, True),
    "camera": (_open_camera, True),
    "video": (lambda mp, tmp: f"video:{_video(tmp, SIZE)}", False),
    "plain-path": (lambda mp, tmp: str(_video(tmp, SIZE)), False),
    "folder": (_open_folder, False),
    "rosbag": (_open_rosbag, False),
}


def test_the_contract_cases_cover_every_source_class_and_every_kind():
    classes = {
        value
        for value in vars(sensors).values()
        if isinstance(value, type) and issubclass(value, sensors.FrameSourceBase)
    }
    # StampedOnArrival wraps the others; it is checked through them below.
    assert classes - {sensors.FrameSourceBase, sensors.StampedOnArrival} == {
        kind.source_class for kind in sensors.SENSORS
    }
    assert {case.split("-")[0] for case in CONTRACT_CASES} - {"plain"} == {
        kind.name for kind in sensors.SENSORS
    }
    for kind in sensors.SENSORS:
        assert kind.help.startswith(f"{kind.name}:") and kind.live in sensors.LIVENESS


@pytest.mark.parametrize("case", sorted(CONTRACT_CASES))
def test_every_source_keeps_the_contract(case, monkeypatch, tmp_path):
    make_spec, live = CONTRACT_CASES[case]
    spec = make_spec(monkeypatch, tmp_path)
    kind, target = sensors.parse_spec(spec)
    source = open_source(spec, fps=30.0)  # the fps: a folder's timing, ignored by the rest
    assert isinstance(source, kind.source_class) and source.geometry == kind.geometry
    # Liveness is the table's; a live source is read on arrival (a thread stamps it).
    assert source.live is live is kind.is_live(target)
    reader = sensors.read_on_arrival(source)
    assert isinstance(reader, sensors.StampedOnArrival) is live
    times, frames = [], []
    with reader:
        for _ in range(CONTRACT_FRAMES):
            t, frame = reader.read()
            times.append(t)
            frames.append(frame)
    # Frames of the declared size, uint8, three channels in the table's (BGR) order.
    declared = kind.geometry.frame_size(reader.last_raw_size)
    assert kind.channel_order == "BGR"
    for frame in frames:
        assert frame.shape == (*declared, 3) and frame.dtype == np.uint8
        blue, red = frame[..., 0].mean(), frame[..., 2].mean()
        assert blue > red + 100, (case, blue, red)
    assert all(np.isfinite(times)) and times == sorted(times)
    source.close()  # idempotent: the reader closed it already
    source.close()


@pytest.mark.parametrize(
    ("names", "mode", "message"),
    [
        ({"video0": "Integrated Camera: Integrated C"}, (1280, 720), "is 'Integrated Camera"),
        ({}, (1920, 1080), "delivers 1920x1080 px, not a GelSight Mini's 4:3 stream"),
    ],
)
def test_mini_refuses_a_camera_that_is_not_a_mini(names, mode, message, monkeypatch, tmp_path):
    _v4l_names(monkeypatch, tmp_path, **names)
    _fake_capture(monkeypatch, (mode[1], mode[0]), mode=mode)
    with pytest.raises(SensorError, match=message) as err:
        open_source("mini:0")
    assert "\n" not in str(err.value) and "camera:0" in str(err.value)
    # The same camera is fine as what it is.
    with open_source("camera:0") as camera:
        assert camera.read()[1].shape == (mode[1], mode[0], 3)


def test_a_mini_by_its_by_id_path_is_named_through_its_device(monkeypatch, tmp_path):
    _v4l_names(monkeypatch, tmp_path, video2="GelSight Mini R0B 2BG8-XYZ")
    link = tmp_path / "usb-GelSight_Mini-video-index0"
    link.symlink_to(tmp_path / "video2")
    (tmp_path / "video2").touch()
    assert sensors.device_name(str(link)) == "GelSight Mini R0B 2BG8-XYZ"
    assert sensors.device_name("7") is None  # no such device in sysfs: nothing to check


@pytest.mark.parametrize("text", ["1,2 3,4", "0,0 1,0 1,1 0,x", "0,0 1,0 1,1 0,1,2"])
def test_parse_corners_refuses_anything_but_four_points(text: str) -> None:
    from tactile_compliance.data.image_ops import parse_corners

    with pytest.raises(ValueError, match="four points"):
        parse_corners(text)
    assert parse_corners("0,0 127,0 127,95 0,95")[2] == (127.0, 95.0)


def test_calibrate_writes_the_warped_reference_with_its_crop_and_never_a_foreign_png(tmp_path):
    """Issue 42: ``calibrate --out OUT.json`` writes ``OUT.png``, the warped reference with
    the crop drawn on it; a PNG it did not write is never replaced."""
    from typer.testing import CliRunner

    from tactile_compliance.acquisition.calibration import is_calibration_picture
    from tactile_compliance.cli import app

    write_video(tmp_path / "v.avi", _frames(3, (96, 128)), 25)
    out = tmp_path / "sensor.json"
    corners = "0,0 127,0 127,95 0,95"
    args = ["calibrate", f"video:{tmp_path / 'v.avi'}", "--out", str(out), "--frames", "3"]
    args += ["--corners", corners, "--warp-size", "48x64", "--crop-px", "4"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    picture = tmp_path / "sensor.png"
    assert f"Picture {picture}" in result.output and is_calibration_picture(picture)
    image = cv2.imread(str(picture))
    assert image.shape == (48, 64, 3)  # the warp's size: before the crop
    green = (image[..., 1] == 255) & (image[..., 0] == 0) & (image[..., 2] == 0)
    assert green[4, 4:60].all() and green[4:44, 4].all()  # the crop's edges, 4 px in
    assert not green[2, 2] and not green[24, 32]
    again = CliRunner().invoke(app, args)  # its own picture is replaced
    assert again.exit_code == 0, again.output
    out.unlink()
    cv2.imwrite(str(picture), image)  # now a PNG that is not calibrate's
    refused = CliRunner().invoke(app, args)
    assert refused.exit_code == 2 and "sensor.png exists and is not a calibration picture" in (
        refused.output
    )
    assert not out.exists() and not is_calibration_picture(picture)
