"""Depth, recording and export survive hostile or careless inputs (issue 43).

Every case of the issue's probe that is this file's (the units of each grasp, the resume
record and the estimates a model cannot make are tested elsewhere) gives one error line
and a non-zero exit code, or the correct result, and loses nothing:

- every file goes through ``outputs.atomic_file``, which never writes through a link;
- a full disk leaves no truncated file and no half-recorded grasp;
- a truncated image or video is an error, not a shorter recording;
- sizes (image headers, layer sizes) are checked before anything is allocated;
- numbers that are finite but absurd are refused where they are read.
"""

from __future__ import annotations

import errno
import json
import math
import os
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest
import torch
from typer.testing import CliRunner

import tactile_compliance
from tactile_compliance.acquisition import calibration as calibration_module
from tactile_compliance.acquisition.calibration import (
    SensorCalibration,
    calibrate_depth,
    read_circles,
    read_image,
)
from tactile_compliance.acquisition.capture import capture_grasp
from tactile_compliance.acquisition.readings import Readings
from tactile_compliance.acquisition.recording import (
    OBJECT_TABLE_FILE,
    ObjectInfo,
    write_grasp,
)
from tactile_compliance.acquisition.sensors import FolderSource, open_source
from tactile_compliance.cli import EXIT_BAD_INPUT, EXIT_FAILED, app
from tactile_compliance.data.depth_model import CalibratedDepthModel
from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.models import create_model
from tactile_compliance.outputs import MARKER_NAME, OutputExistsError, atomic_file
from tactile_compliance.runs.checkpoint import save_checkpoint
from tactile_compliance.runs.metrics import grouped_metrics, r2
from tactile_compliance.runs.run_inputs import RunInputs
from test_recording import make_grasp
from test_recording_reliability import captured
from toy_store import make_toy_store

runner = CliRunner()
SIZE = (48, 64)  # (H, W) of the small sensor frames made here


def _one_line(result, code: int = EXIT_BAD_INPUT) -> str:
    """The one error line of a failed command (no traceback, no estimate)."""
    lines = [line for line in result.output.strip().splitlines() if line.startswith("error: ")]
    assert result.exit_code == code, result.output
    assert len(lines) == 1, result.output
    assert "Traceback" not in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    return lines[0]


def _invoke(*args):
    return runner.invoke(app, [str(a) for a in args])


def _frame(seed: int = 0, press: tuple[int, int] | None = (30, 20)) -> np.ndarray:
    """A lit sensor frame (colour gradients and read noise), with a bright press at (x, y)."""
    rng = np.random.default_rng(seed)
    h, w = SIZE
    frame = np.zeros((h, w, 3), np.float64)
    frame[..., 0] = np.linspace(60, 120, w)[None]
    frame[..., 1] = np.linspace(80, 140, h)[:, None]
    frame[..., 2] = 100
    if press is not None:
        rows, cols = np.mgrid[0:h, 0:w]
        blob = np.exp(-((cols - press[0]) ** 2 + (rows - press[1]) ** 2) / 40.0)
        frame += blob[..., None] * np.array([60.0, -30.0, 40.0])
    frame += rng.normal(0, 1.0, frame.shape)
    return np.clip(frame, 0, 255).astype(np.uint8)


def _depth_model(size: tuple[int, int], weight: float = 0.3, seed: int = 0):
    """A small depth model of the fitted kind (weights well below 1)."""
    rng = np.random.default_rng(seed)
    widths = (5, 32, 32, 2)
    layers = [
        (
            rng.normal(0, weight, (widths[k], widths[k + 1])).astype(np.float32),
            np.zeros(widths[k + 1], np.float32),
        )
        for k in range(3)
    ]
    scale = np.full(5, 5.0, np.float32)
    return CalibratedDepthModel(10.0, size, 4.0, 0.01, layers, scale)


@pytest.fixture(scope="module")
def sensor(tmp_path_factory):
    """Images and a depth calibration of one small colour sensor."""
    root = tmp_path_factory.mktemp("sensor")
    reference = _frame(9, press=None)
    cv2.imwrite(str(root / "reference.png"), reference)
    presses = root / "presses"
    presses.mkdir()
    for k, place in enumerate([(20, 15), (40, 30), (30, 20), (45, 12)]):
        cv2.imwrite(str(presses / f"press_{k}.png"), _frame(k, place))
        cv2.imwrite(
            str(presses / f"press_{k}.jpg"), _frame(k, place), [cv2.IMWRITE_JPEG_QUALITY, 95]
        )
    cv2.imwrite(str(root / "held.png"), _frame(7, (25, 25)))
    cv2.imwrite(str(root / "held.jpg"), _frame(7, (25, 25)), [cv2.IMWRITE_JPEG_QUALITY, 95])
    calibration = SensorCalibration(
        reference=reference,
        geometry=calibration_module.FrameGeometry(),
        px_per_mm=10.0,
        depth_model=_depth_model(SIZE),
    )
    calibration.save(root / "sensor.json")
    return {"root": root, "presses": presses, "reference": reference, "calibration": calibration}


@pytest.fixture(scope="module")
def grasp(tmp_path_factory):
    return make_grasp(tmp_path_factory.mktemp("grasp"), (60, 84))


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    root = tmp_path_factory.mktemp("model")
    torch.manual_seed(0)
    model = create_model("top10nn", inputs="Image")
    run_inputs = RunInputs((72, 72), (72, 72), NormalisationConstants(), model.inputs)
    return save_checkpoint(root / "best.pt", model, run_inputs=run_inputs, config={}, seed=0)


# ====================================================================== one writer
def test_atomic_file_refuses_a_link_at_its_path(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    link = tmp_path / "out.json"
    link.symlink_to(victim)
    with pytest.raises(OutputExistsError, match="symbolic link"), atomic_file(link) as handle:
        handle.write("{}")
    assert victim.read_text() == "precious" and link.is_symlink()


def test_atomic_file_never_follows_a_link_at_its_temp_name(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    (tmp_path / "out.json.tmp").symlink_to(victim)  # planted, or a killed writer's
    with atomic_file(tmp_path / "out.json") as handle:
        handle.write("{}")
    assert victim.read_text() == "precious"
    assert (tmp_path / "out.json").read_text() == "{}" and not (tmp_path / "out.json").is_symlink()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.json", "victim.txt"]


def test_atomic_file_names_the_file_not_its_temp_file(tmp_path):
    with pytest.raises(FileNotFoundError) as caught, atomic_file(tmp_path / "no" / "x.json"):
        pass
    assert ".tmp" not in str(caught.value) and "no such folder" in str(caught.value)


def _depth_dir(sensor, tmp_path) -> Path:
    """A `depth` output directory (marked) with one earlier map."""
    out = tmp_path / "out"
    root = sensor["root"]
    result = _invoke(
        "depth", root / "reference.png", "--calibration", root / "sensor.json", "--out", out
    )
    assert result.exit_code == 0, result.output
    return out


# (planted name, exit code, whether the map is then written)
LINKS = [
    ("held.npy", EXIT_BAD_INPUT, False),
    ("held.npy.tmp", 0, True),
    ("held.png", EXIT_BAD_INPUT, True),
]


@pytest.mark.parametrize(("name", "code", "written"), LINKS, ids=[c[0] for c in LINKS])
def test_depth_never_writes_through_a_planted_link(sensor, tmp_path, name, code, written):
    out = _depth_dir(sensor, tmp_path)
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    (out / name).symlink_to(victim)
    root = sensor["root"]
    result = _invoke(
        "depth", root / "held.png", "--calibration", root / "sensor.json", "--out", out, "--png"
    )
    assert victim.read_text() == "precious"
    if code:
        assert "symbolic link" in _one_line(result, code)
        assert (out / name).is_symlink()  # the link is left as it was
    else:
        assert result.exit_code == 0, result.output
    npy = out / "held.npy"
    if written:
        assert npy.is_file() and not npy.is_symlink()
        assert np.load(npy).shape == SIZE


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="RLIMIT_FSIZE is Linux's")
def test_depth_on_a_full_disk_exits_1_and_leaves_no_truncated_file(sensor, tmp_path):
    """A file-size limit (what a full disk or quota does to a write) hits the 12 kB map."""
    out = tmp_path / "out"
    root = sensor["root"]
    code = (
        "import resource, signal, sys\n"
        "signal.signal(signal.SIGXFSZ, signal.SIG_IGN)\n"
        "resource.setrlimit(resource.RLIMIT_FSIZE, (4000, resource.RLIM_INFINITY))\n"
        "from tactile_compliance.cli import app\n"
        "sys.argv = ['tactile-compliance'] + sys.argv[1:]\n"
        "app()\n"
    )
    args = ["depth", root / "held.png", "--calibration", root / "sensor.json", "--out", out]
    src = Path(tactile_compliance.__file__).resolve().parents[1]  # the package under test
    env = {
        **os.environ,
        "PYTHONPATH": f"{src}{os.pathsep}{os.environ.get('PYTHONPATH', '')}",
    }
    proc = subprocess.run(
        [sys.executable, "-c", code, *map(str, args)], capture_output=True, text=True, env=env
    )
    output = proc.stdout + proc.stderr
    assert proc.returncode == EXIT_FAILED, output
    assert output.count("error: ") == 1 and "Traceback" not in output, output
    assert sorted(p.name for p in out.iterdir()) == [MARKER_NAME]  # no truncated .npy or .tmp


def test_record_on_a_full_disk_commits_no_grasp_without_its_table_row(tmp_path, monkeypatch):
    out = tmp_path / "data"
    write_grasp(captured(), out, ObjectInfo("ball", 1e5))
    before = (out / OBJECT_TABLE_FILE).read_bytes()

    def full(self, *args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(pd.DataFrame, "to_csv", full)
    with pytest.raises(OSError, match="No space left"):
        write_grasp(captured(), out, ObjectInfo("ball", 1e5))
    monkeypatch.undo()
    assert sorted(p.name for p in (out / "ball").iterdir()) == ["grasp=0", "metadata.json"]
    assert (out / OBJECT_TABLE_FILE).read_bytes() == before
    # The re-run records the grasp once: grasp=1, and the table says 2 trials.
    assert write_grasp(captured(), out, ObjectInfo("ball", 1e5)).grasp == 1
    rows = pd.read_csv(out / OBJECT_TABLE_FILE, dtype=str, keep_default_na=False)
    assert rows.set_index("Label").loc["ball", "Trials Recorded?"] == "2"


def test_record_takes_the_grasp_back_when_the_table_cannot_replace_the_old(tmp_path, monkeypatch):
    out = tmp_path / "data"
    write_grasp(captured(), out, ObjectInfo("ball", 1e5))
    replace = os.replace

    def failing(src, dst, *args, **kwargs):
        if Path(dst).name == OBJECT_TABLE_FILE:
            raise OSError(errno.EIO, "Input/output error")
        return replace(src, dst, *args, **kwargs)

    monkeypatch.setattr(os, "replace", failing)
    with pytest.raises(OSError, match="Input/output"):
        write_grasp(captured(), out, ObjectInfo("ball", 1e5))
    monkeypatch.undo()
    assert sorted(p.name for p in (out / "ball").iterdir()) == ["grasp=0", "metadata.json"]
    assert not list(out.glob("*.tmp"))


# ====================================================================== truncated inputs
def _cut(path: Path, share: float, out: Path) -> Path:
    data = path.read_bytes()
    out.write_bytes(data[: int(len(data) * share)])
    return out


@pytest.mark.parametrize("suffix", [".jpg", ".png"])
def test_a_truncated_image_is_refused(sensor, tmp_path, suffix):
    cut = _cut(sensor["root"] / f"held{suffix}", 0.6, tmp_path / f"held{suffix}")
    kind = {".jpg": "JPEG", ".png": "PNG"}[suffix]
    with pytest.raises(ValueError, match=f"a truncated {kind}"):
        read_image(cut)
    intact = read_image(sensor["root"] / f"held{suffix}")
    assert intact.shape == (*SIZE, 3)


def test_a_jpeg_with_trailing_bytes_after_its_end_is_read(sensor, tmp_path):
    path = tmp_path / "trailing.jpg"
    path.write_bytes((sensor["root"] / "held.jpg").read_bytes() + b"\x00" * 64)
    assert read_image(path).shape == (*SIZE, 3)


def test_calibrate_depth_and_depth_refuse_a_truncated_jpeg(sensor, tmp_path):
    presses = tmp_path / "presses"
    presses.mkdir()
    for k in range(4):
        source = sensor["presses"] / f"press_{k}.jpg"
        (presses / source.name).write_bytes(source.read_bytes())
    _cut(presses / "press_2.jpg", 0.6, presses / "press_2.jpg")
    root = sensor["root"]
    result = _invoke(
        "calibrate-depth", presses, "--reference", root / "reference.png",
        "--ball-radius-mm", 4, "--px-per-mm", 10, "--out", tmp_path / "c.json",
    )  # fmt: skip
    assert "press_2.jpg: a truncated JPEG" in _one_line(result)
    result = _invoke(
        "depth",
        presses / "press_2.jpg",
        "--calibration",
        root / "sensor.json",
        "--out",
        tmp_path / "d",
    )
    assert "truncated" in _one_line(result) and not (tmp_path / "d").exists()


def test_a_truncated_frame_of_a_folder_is_skipped_with_its_cause(sensor, tmp_path):
    folder = tmp_path / "frames"
    folder.mkdir()
    for k in range(3):
        cv2.imwrite(str(folder / f"{k}.jpg"), _frame(k))
    _cut(folder / "1.jpg", 0.5, folder / "1.jpg")
    source = FolderSource(folder, fps=10)
    assert source.read() is not None
    with pytest.raises(calibration_module.FrameError, match=r"1\.jpg: a truncated JPEG"):
        source.read()


@pytest.mark.parametrize("command", ["record", "live"])
def test_a_video_cut_short_is_an_error_not_a_shorter_grasp(grasp, checkpoint, tmp_path, command):
    cut = _cut(grasp["video"], 0.45, tmp_path / "grasp.avi")
    if command == "record":
        args = ["record", f"video:{cut}", "--out", tmp_path / "data", "--object", "ball"]
        args += ["--modulus", "1e5"]
    else:
        args = ["live", checkpoint, f"video:{cut}", "--device", "cpu"]
    result = _invoke(*args, "--readings", grasp["readings"])
    assert "the video ends after" in _one_line(result) and "truncated" in result.output
    assert not (tmp_path / "data" / "ball").exists()
    # The whole video is read as before.
    with open_source(f"video:{grasp['video']}") as source:
        assert len(list(source)) == len(grasp["force"])


# ====================================================================== calibration numbers
def _tampered(sensor, tmp_path, change) -> Path:
    doc = json.loads((sensor["root"] / "sensor.json").read_text())
    change(doc["depth_model"])
    path = tmp_path / "tampered.json"
    path.write_text(json.dumps(doc))
    return path


# (case id, a change of the depth model's JSON, what the message says)
HUGE = [
    ("weight 1e30", lambda m: m["layers"][0]["weight"][0].__setitem__(0, 1e30), "layer 0"),
    ("weight 1e6", lambda m: m["layers"][2]["weight"][1].__setitem__(0, 1e6), "layer 2"),
    ("bias 1e30", lambda m: m["layers"][1]["bias"].__setitem__(3, -1e30), "layer 1"),
    ("input_scale 1e30", lambda m: m["input_scale"].__setitem__(0, 1e30), "input_scale"),
    ("input_scale 0", lambda m: m["input_scale"].__setitem__(2, 0.0), "input_scale"),
    ("ball radius 1e300", lambda m: m.update(ball_radius_mm=1e300), "ball_radius_mm"),
]


@pytest.mark.parametrize(("name", "change", "says"), HUGE, ids=[c[0] for c in HUGE])
def test_finite_but_huge_calibration_numbers_are_refused_at_load(
    sensor, tmp_path, name, change, says
):
    path = _tampered(sensor, tmp_path, change)
    with pytest.raises(ValueError, match=says):
        SensorCalibration.load(path)
    root = sensor["root"]
    result = _invoke("depth", root / "held.png", "--calibration", path, "--out", tmp_path / "d")
    assert "damaged sensor calibration" in _one_line(result)
    assert "peak" not in result.output and not (tmp_path / "d").exists()


def test_a_depth_model_that_gives_nan_says_so(sensor):
    model = sensor["calibration"].depth_model
    layers = [(w.copy(), b.copy()) for w, b in model.layers]
    layers[0][0][:] = 90.0  # within the bound, but the integration overflows for this frame
    broken = CalibratedDepthModel(
        model.px_per_mm, model.frame_size, 4.0, 0.01, layers, model.input_scale
    )
    diff = np.full((1, *SIZE, 3), 0.5, np.float32)
    diff[0, 10:30, 10:30] = 1e37  # not a difference image: the slopes overflow
    with (
        np.errstate(over="ignore", invalid="ignore"),
        pytest.raises(ValueError, match="non-finite"),
    ):
        broken.depth_mm(diff)


# ====================================================================== --circles
# (case id, the file's content, what the message says)
CIRCLES = [
    ("centre (1e9, -1e9)", "press_0.png (1e9, -1e9) 8\n", "lies outside the 64x48 px frame"),
    ("centre inf", "press_0.png (1e999, 10) 8\n", "centre must be finite"),
    ("radius 1e-9", "press_0.png (30, 20) 1e-9\n", "below 3 px"),
    ("radius 1e6", "press_0.png (30, 20) 1e6\n", "larger than half"),
    ("a name twice", "press_0.png (30, 20) 8\npress_0.png,20,15,8\n", "already has a circle"),
    ("binary", bytes(range(256)) * 4, "circles.txt: not a text file"),
]


@pytest.mark.parametrize(("name", "content", "says"), CIRCLES, ids=[c[0] for c in CIRCLES])
def test_bad_circles_are_refused_with_one_line(sensor, tmp_path, name, content, says):
    path = tmp_path / "circles.txt"
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content)
    root = sensor["root"]
    result = _invoke(
        "calibrate-depth", *sorted(sensor["presses"].glob("*.png")), "--reference",
        root / "reference.png", "--ball-radius-mm", 4, "--px-per-mm", 10,
        "--out", tmp_path / "c.json", "--circles", path,
    )  # fmt: skip
    assert says in _one_line(result)
    assert not (tmp_path / "c.json").exists()


def test_a_press_that_is_the_reference_is_refused(sensor):
    presses = [(f"p{k}", _frame(k, (20 + 8 * k, 20))) for k in range(3)]
    with pytest.raises(ValueError, match="p1 is the no-contact reference itself"):
        calibrate_depth(
            presses,
            ball_radius_mm=4.0,
            px_per_mm=10.0,
            reference=presses[1][1].copy(),
            circles={"p1": calibration_module.ContactCircle(28.0, 20.0, 6.0)},
            epochs=1,
        )


def test_circles_read_as_before(tmp_path):
    path = tmp_path / "c.txt"
    path.write_text("a.png (10, 12) 5\n# note\nb.png,3,4,6\n")
    assert set(read_circles(path)) == {"a.png", "b.png"}


# ====================================================================== record
@pytest.mark.parametrize(
    "name",
    [OBJECT_TABLE_FILE, "DATASET_OBJECTS_AND_COMPLIANCE.CSV", "generation.json"],
)
def test_an_object_named_like_a_layout_file_is_refused(name):
    with pytest.raises(ValueError, match="name of a file of the dataset layout"):
        ObjectInfo(name, 1e5)


def test_record_refuses_a_layout_file_name_on_the_command_line(grasp, tmp_path):
    result = _invoke(
        "record", f"video:{grasp['video']}", "--out", tmp_path / "data", "--object",
        OBJECT_TABLE_FILE, "--modulus", "1e5", "--readings", grasp["readings"],
    )  # fmt: skip
    assert "dataset layout" in _one_line(result) and not (tmp_path / "data").exists()


def _ms_readings(grasp, tmp_path, offset_ms: float = 0.0) -> Path:
    table = pd.read_csv(grasp["readings"])
    table["timestamp_s"] = table["timestamp_s"] * 1000.0 + offset_ms
    path = tmp_path / "ms.csv"
    table.to_csv(path, index=False)
    return path


@pytest.mark.parametrize("command", ["record", "live"])
def test_readings_stamped_in_milliseconds_are_named(grasp, checkpoint, tmp_path, command):
    readings = _ms_readings(grasp, tmp_path)
    if command == "record":
        args = ["record", f"video:{grasp['video']}", "--out", tmp_path / "data"]
        args += ["--object", "ball", "--modulus", "1e5"]
    else:
        args = ["live", checkpoint, f"video:{grasp['video']}", "--device", "cpu"]
    result = _invoke(*args, "--readings", readings)
    assert "timestamps look like milliseconds; give seconds" in _one_line(result)
    assert "skipped" not in result.output


def test_millisecond_readings_of_a_later_clock_are_named_before_any_skip(
    grasp, checkpoint, tmp_path
):
    readings = _ms_readings(grasp, tmp_path, offset_ms=5_000_000.0)
    args = ["live", checkpoint, f"video:{grasp['video']}", "--readings", readings]
    result = _invoke(*args, "--readings-offset-s", 5000, "--device", "cpu")
    assert "milliseconds" in _one_line(result) and "skipped" not in result.output


def test_readings_in_seconds_pass_the_milliseconds_check(grasp):
    frames = open_source(f"video:{grasp['video']}")
    with frames:
        readings = Readings.from_csv(grasp["readings"])
        captured_grasp = capture_grasp(frames, readings, stop_on_release=False)
    assert len(captured_grasp) == len(grasp["force"])


def test_greyscale_frames_are_refused_by_a_colour_depth_model(sensor, tmp_path):
    grey = cv2.cvtColor(cv2.imread(str(sensor["root"] / "held.png")), cv2.COLOR_BGR2GRAY)
    cv2.imwrite(str(tmp_path / "grey.png"), grey)
    root = sensor["root"]
    result = _invoke(
        "depth",
        tmp_path / "grey.png",
        "--calibration",
        root / "sensor.json",
        "--out",
        tmp_path / "d",
    )
    assert "greyscale" in _one_line(result) and not (tmp_path / "d").exists()
    frames = np.repeat(captured().frames.mean(axis=3, keepdims=True).astype(np.uint8), 3, axis=3)
    grey_grasp = captured()
    grey_grasp.frames = frames
    colour = SensorCalibration(
        reference=_frame(3, None)[:24, :32],
        geometry=calibration_module.FrameGeometry(),
        depth_model=_depth_model((24, 32)),
    )
    with pytest.raises(ValueError, match="greyscale"):
        write_grasp(grey_grasp, tmp_path / "data", ObjectInfo("ball", 1e5), sensor=colour)
    assert not (tmp_path / "data").exists()


# ====================================================================== export
def test_export_to_a_link_to_a_directory_refuses_and_moves_nothing(checkpoint, tmp_path):
    target = tmp_path / "target"
    assert _invoke("export", checkpoint, "--safetensors", target).exit_code == 0
    (target / "notes.txt").write_text("mine")
    before = sorted(p.name for p in target.iterdir())
    link = tmp_path / "link"
    link.symlink_to(target)
    result = _invoke("export", checkpoint, "--safetensors", link)
    assert "symbolic link" in _one_line(result)
    assert link.is_symlink() and sorted(p.name for p in target.iterdir()) == before
    assert (target / "notes.txt").read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link", "target"]


def test_export_to_a_link_as_onnx_file_refuses_before_the_safetensors(checkpoint, tmp_path):
    pytest.importorskip("onnx")
    victim = tmp_path / "victim.onnx"
    victim.write_text("mine")
    (tmp_path / "m.onnx").symlink_to(victim)
    args = ["export", checkpoint, "--onnx", tmp_path / "m.onnx", "--safetensors", tmp_path / "e"]
    assert "symbolic link" in _one_line(_invoke(*args))
    assert victim.read_text() == "mine" and not (tmp_path / "e").exists()


@pytest.mark.parametrize("licence", ["mit\n# heading\n<script>", "mit # x", "", "a" * 80, '"mit"'])
def test_a_licence_that_is_no_identifier_is_refused(checkpoint, tmp_path, licence):
    result = _invoke("export", checkpoint, "--safetensors", tmp_path / "e", "--license", licence)
    assert "not a licence identifier" in _one_line(result) and not (tmp_path / "e").exists()


def test_spdx_licences_reach_the_card(checkpoint, tmp_path):
    result = _invoke(
        "export", checkpoint, "--safetensors", tmp_path / "e", "--license", "cc-by-4.0"
    )
    assert result.exit_code == 0, result.output
    assert "\nlicense: cc-by-4.0\n" in (tmp_path / "e" / "README.md").read_text()


# ====================================================================== smaller ones
@pytest.mark.parametrize(
    ("name", "value"),
    [("force_scale_n", 1e300), ("force_scale_n", 1e-300), ("width_scale_m", 1e9),
     ("estimate_log10_span", 1e300), ("estimate_log10_min", -1e300)],
)  # fmt: skip
def test_absurd_normalisation_scales_are_refused(name, value):
    with pytest.raises(ValueError, match=f"{name} .* outside the plausible"):
        NormalisationConstants(**{name: value})


def test_a_checkpoint_with_force_scale_1e300_gives_no_estimate(checkpoint, tmp_path):
    payload = torch.load(checkpoint, weights_only=True)
    payload["run_inputs"]["normalisation"]["force_scale_n"] = 1e300
    torch.save(payload, tmp_path / "b.pt")
    store = make_toy_store(tmp_path / "store", n_objects=2, grasps=1).path
    result = _invoke("predict", tmp_path / "b.pt", store, "--device", "cpu")
    assert "force_scale_n" in _one_line(result)


@pytest.mark.parametrize(
    "override",
    ["model.backbone_weights=/x.pth", "training.lr=1", "model.name=res_tf", "inputs=ALL"],
)
def test_pretrain_refuses_settings_it_never_reads(tmp_path, override):
    result = _invoke(
        "pretrain", tmp_path / "store", "--backbone", "top10nn-cnn", "--out", tmp_path / "w.pt",
        "--set", override,
    )  # fmt: skip
    assert "pretrain does not read" in _one_line(result) and not (tmp_path / "w.pt").exists()


def test_r2_of_equal_true_moduli_is_undefined_not_huge():
    assert math.isnan(r2([1.3e5] * 5, [1.43e5] + [1.17e5] * 4))
    assert math.isnan(r2([1e5, 1e5], [1e5, 1e5]))
    frame = pd.DataFrame(
        {
            "modulus_pa": [2.7e5] * 3 + [1e6, 2e6],
            "pred_pa": [3e5, 2e5, 3.3e5, 1e6, 2e6],
            "material": ["Foam"] * 3 + ["Rubber"] * 2,
            "shape": ["Sphere"] * 5,
        }
    )
    groups = grouped_metrics(frame).set_index("group")
    assert math.isnan(groups.loc["Foam", "r2"]) and groups.loc["Rubber", "r2"] == pytest.approx(1)
    assert groups.loc["all", "r2"] > -10


def test_evaluate_says_why_a_group_has_no_r2(monkeypatch, tmp_path):
    from tactile_compliance.evaluation import evaluate as evaluate_module
    from tactile_compliance.evaluation.evaluate import Evaluation

    groups = pd.DataFrame(
        [
            {"grouping": "all", "group": "all", "n": 5, "r2": 0.5, "nmse": 0.01},
            {"grouping": "material", "group": "Foam", "n": 3, "r2": math.nan, "nmse": 0.02},
        ]
    )
    fake = Evaluation(pd.DataFrame(), {"n": 5, "r2": 0.5}, groups)
    monkeypatch.setattr(evaluate_module, "evaluate_run", lambda *args, **kwargs: fake)
    result = _invoke("evaluate", tmp_path)
    assert result.exit_code == 0, result.output
    assert "n/a" in result.output and "true moduli are all equal" in result.output
    assert "nan" not in result.output.lower().replace("n/a", "")
    result = _invoke("evaluate", tmp_path, "--json")
    assert json.loads(result.output)["groups"][1]["r2"] is None


# ====================================================================== sizes first
def _huge_png(path: Path, side: int = 100_000) -> Path:
    def chunk(kind: bytes, data: bytes) -> bytes:
        body = kind + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body))

    header = struct.pack(">IIBBBBB", side, side, 8, 2, 0, 0, 0)
    idat = chunk(b"IDAT", zlib.compress(b"\0" * 100))
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + idat + chunk(b"IEND", b""))
    return path


def _huge_jpeg(path: Path, sensor) -> Path:
    data = bytearray((sensor["root"] / "held.jpg").read_bytes())
    sof = data.find(b"\xff\xc0")
    data[sof + 5 : sof + 9] = struct.pack(">HH", 60000, 60000)
    path.write_bytes(bytes(data))
    return path


@pytest.mark.parametrize("kind", ["png", "jpeg"])
def test_an_image_header_claiming_a_huge_size_is_refused_before_decoding(sensor, tmp_path, kind):
    path = (
        _huge_png(tmp_path / "f.png") if kind == "png" else _huge_jpeg(tmp_path / "f.jpg", sensor)
    )
    with pytest.raises(ValueError, match=r"its header says .* so it was not decoded"):
        read_image(path)
    root = sensor["root"]
    for args in (
        ["depth", path, "--calibration", root / "sensor.json", "--out", tmp_path / "d"],
        ["depth", root / "held.png", "--reference", path, "--out", tmp_path / "d"],
        ["calibrate-depth", path, root / "held.png", "--ball-radius-mm", 4, "--px-per-mm", 10,
         "--out", tmp_path / "c.json"],
    ):  # fmt: skip
        assert "not decoded" in _one_line(_invoke(*args))


def test_record_refuses_a_huge_reference_image(grasp, tmp_path):
    result = _invoke(
        "record", f"video:{grasp['video']}", "--out", tmp_path / "data", "--object", "ball",
        "--modulus", "1e5", "--readings", grasp["readings"], "--reference",
        _huge_png(tmp_path / "r.png"),
    )  # fmt: skip
    assert "not decoded" in _one_line(result)


@pytest.mark.parametrize("size", [100_000_000, 300_000])
def test_a_huge_layer_size_is_refused_before_it_is_allocated(checkpoint, tmp_path, size):
    payload = torch.load(checkpoint, weights_only=True)
    payload["hparams"]["img_feature_size"] = size
    torch.save(payload, tmp_path / "b.pt")
    store = make_toy_store(tmp_path / "store", n_objects=2, grasps=1).path
    result = _invoke("predict", tmp_path / "b.pt", store, "--device", "cpu")
    line = _one_line(result)
    assert "refused before building the model" in line and "do not fit 'top10nn'" in line


def test_a_huge_layer_size_in_config_json_is_refused_before_it_is_allocated(checkpoint, tmp_path):
    from tactile_compliance.inference import ComplianceEstimator
    from tactile_compliance.inference.export import export_safetensors

    pytest.importorskip("safetensors")
    export_safetensors(checkpoint, tmp_path / "e")
    config = json.loads((tmp_path / "e" / "config.json").read_text())
    config["hparams"]["img_feature_size"] = 100_000_000
    (tmp_path / "e" / "config.json").write_text(json.dumps(config))
    with pytest.raises(ValueError, match="refused before"):
        ComplianceEstimator.from_pretrained(tmp_path / "e", device="cpu")


# ====================================================================== the right cause
def test_calibrate_depth_checks_its_out_before_the_fit(sensor, tmp_path, monkeypatch):
    def no_fit(*args, **kwargs):
        raise AssertionError("the fit ran before --out was checked")

    monkeypatch.setattr(calibration_module, "calibrate_depth", no_fit)
    root = sensor["root"]
    result = _invoke(
        "calibrate-depth", sensor["presses"], "--reference", root / "reference.png",
        "--ball-radius-mm", 4, "--px-per-mm", 10, "--out", tmp_path / "missing" / "c.json",
    )  # fmt: skip
    line = _one_line(result)
    assert "no such folder" in line and ".tmp" not in line


def test_a_moved_aside_checkpoint_gets_our_own_message(tmp_path):
    import pathlib
    import warnings

    from tactile_compliance.training.resume import find_resume_point

    directory = tmp_path / "run" / "checkpoints"
    directory.mkdir(parents=True)
    # A class the safe load refuses (what a damaged or foreign checkpoint holds).
    payload = {"state_dict": pathlib.PurePosixPath("x"), "loops": 1, "epoch": 1}
    torch.save(payload, directory / "last.ckpt")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert find_resume_point(tmp_path / "run") is None
    (message,) = [str(w.message) for w in caught if "last.ckpt" in str(w.message)]
    assert (
        "Python objects other than tensors" in message
        and "moved it to last.ckpt.corrupt" in message
    )
    assert "Weights only" not in message and "weights_only" not in message and "\n" not in message
