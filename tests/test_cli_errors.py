"""Mistakes a new user makes, each answered by one line that names the real cause (the
option, the file, what to install) and a non-zero exit, in the command's own process: no
traceback, no third-party advice, no warnings before it, nothing left behind.

Where each mistake of issue 29 is tested:

- here, table-driven (``_cases``): a text file, a torch file of pickled objects and a
  truncated file as a checkpoint; ``--readings /nonexistent.csv``; internal names
  (``--objects 0``, ``--window`` with ``--window-s``); an option under its old and new
  name; a config key typo; ``split-summary`` given two directories, a missing split or a
  binary file (the swapped order is accepted: tests/test_cli.py);
- here, one test each: ``export --onnx`` without onnx; ``calibrate camera:7`` without
  OpenCV's warnings; a config typo reported before torch and Lightning load; ``--device
  cuda`` without a GPU; every ``device`` default;
- here, table-driven, the mistakes of issue 42: a readings CSV separated by ``;``, an
  import path cut short (did you mean), ``--fingers markers`` on a markerless-only tree,
  frames too small for Top10NN and a missing ``--split`` file, and typos of a model,
  input strategy, preset and experiment (did you mean); the name and path mistakes are
  also checked to be answered before torch loads;
- tests/test_cli_help.py: values outside the choices (``--fingers markeless``, ...),
  unknown options, missing arguments; a forgotten ``live`` source;
- tests/test_recording.py: ``live`` without an estimate (estimates missing, frame size,
  clock mismatch, too weak a grasp); ``record`` of a grasp without estimates;
- tests/test_inference.py: ``predict`` where no sample has the checkpoint's inputs.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
import typer.main
from typer.testing import CliRunner

from burgess_tree import write_tree
from tactile_compliance.cli import app
from tactile_compliance.data.store import HEADER_FILE

REPO = Path(__file__).resolve().parents[1]
runner = CliRunner()


def _one_error_line(result) -> str:  # type: ignore[no-untyped-def]
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    lines = [line for line in result.output.strip().splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), result.output
    return lines[0]


@pytest.fixture
def files(tmp_path: Path) -> dict[str, Path]:
    """A text file, a torch file holding a pickled object, and a short video."""
    text = tmp_path / "metrics.csv"
    text.write_text("epoch,loss\n1,0.5\n")
    foreign = tmp_path / "foreign.pt"
    torch.save({"args": argparse.Namespace(lr=1e-3)}, foreign)  # not tensors only
    truncated = tmp_path / "best.pt"
    torch.save({"weights": torch.zeros(1000)}, truncated)
    truncated.write_bytes(truncated.read_bytes()[:2000])  # a copy that stopped half-way
    video = tmp_path / "press.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 30, (32, 24))
    for _ in range(5):
        writer.write(np.full((24, 32, 3), 128, np.uint8))
    writer.release()
    store = tmp_path / "store"  # only its header is looked at
    store.mkdir()
    (store / HEADER_FILE).write_text("{}")
    onnx = tmp_path / "model.onnx"
    onnx.write_bytes(b"not read: the suffix is checked first")
    semicolons = tmp_path / "readings-semicolons.csv"
    semicolons.write_text("timestamp_s;force_n;width_m\n0,0;1,5;0,05\n0,1;2,0;0,049\n")
    (tmp_path / "synthetic").mkdir()  # what `import burgess syn...` meant
    recorded = tmp_path / "recorded"  # what `record` writes: the markerless finger only
    write_tree(recorded, grasps=1, augmentations=1)
    for path in [*recorded.rglob("RGB_markers.pkl"), *recorded.rglob("depth_markers.pkl")]:
        path.unlink()
    return {
        "recorded": recorded,
        "semicolons": semicolons,
        "store": store,
        "onnx": onnx,
        "text": text,
        "foreign": foreign,
        "truncated": truncated,
        "video": video,
        "tmp": tmp_path,
    }


def _cases(f: dict[str, Path]) -> dict[str, tuple[list[str], list[str], list[str]]]:
    """label -> (arguments, what the line must say, what it must not say)."""
    tmp = f["tmp"]
    return {
        "a text file as checkpoint": (
            ["predict", str(f["text"]), str(tmp)],
            ["metrics.csv", "a text file", "not a file written by torch.save"],
            ["weights_only", "Traceback"],
        ),
        "a torch file with pickled objects": (
            ["predict", str(f["foreign"]), str(tmp)],
            ["foreign.pt", "Python objects other than tensors"],
            ["weights_only", "add_safe_globals"],
        ),
        "a truncated checkpoint": (
            ["predict", str(f["truncated"]), str(tmp)],
            ["best.pt", "a damaged or incomplete torch file"],
            ["weights_only"],
        ),
        "--readings that does not exist": (
            [
                "record",
                f"video:{f['video']}",
                *("--out", str(tmp / "data"), "--object", "foam", "--modulus", "2e4"),
                *("--readings", str(tmp / "nonexistent.csv")),
            ],
            ["--readings", "nonexistent.csv", "no such file"],
            [],
        ),
        "--objects 0": (
            ["simulate", "--out", str(tmp / "sim"), "--objects", "0"],
            # click's wording of the bound differs between versions; both name it.
            ["'--objects'", ("greater than or equal to 1", "x>=1")],
            ["n_objects"],
        ),
        "--window and --window-s": (
            [
                "live",
                str(f["text"]),
                *(f"video:{f['video']}", "--readings", str(f["text"])),
                *("--window", "5", "--window-s", "1.0"),
            ],
            ["--window (frames) or --window-s (seconds)"],
            ["window_s"],
        ),
        "--window-s 0": (
            [
                "live",
                str(f["text"]),
                *(f"video:{f['video']}", "--readings", str(f["text"])),
                *("--window-s", "0"),
            ],
            ["--window-s must be > 0"],
            ["window_s"],
        ),
        "an experiment on a missing store": (
            [
                *("experiment", "table1", "--quick", "--store", str(tmp / "no-store")),
                *("--out", str(tmp / "runs"), "--results", str(tmp / "results")),
            ],
            ["store not found", "no-store"],
            [],
        ),
        "split-summary given two directories": (
            ["split-summary", str(tmp), str(tmp)],
            ["takes a split JSON file and a store directory", "both directories"],
            ["Errno"],
        ),
        "split-summary given a store and a missing split, in either order": (
            ["split-summary", str(tmp), str(tmp / "split.json")],
            ["split.json: no such split file"],
            ["Errno", "store directory:"],
        ),
        "split-summary given a binary file as the split": (
            ["split-summary", str(f["truncated"]), str(tmp)],
            ["best.pt: not a split JSON (not a text file)"],
            ["codec", "utf-8"],
        ),
        "predict given the store first and the checkpoint second": (
            ["predict", str(f["store"]), str(f["truncated"])],
            ["is a GraspStore, not a checkpoint", "predict CHECKPOINT SOURCE"],
            ["without best.pt"],
        ),
        "predict given an ONNX export": (
            ["predict", str(f["onnx"]), str(f["store"])],
            ["is an ONNX export", "OnnxEstimator"],
            ["Python objects", "never writes such files"],
        ),
        "record with a modulus in an unknown unit": (
            [
                "record",
                f"video:{f['video']}",
                "--out",
                str(tmp / "data"),
                "--object",
                "ball",
                "--modulus",
                "204kPx",
                "--readings",
                str(f["text"]),
            ],
            ["--modulus", "'204kPx' is no modulus", "kPa, MPa or GPa"],
            ["Traceback"],
        ),
        "a config key typo": (
            ["train", "--set", "training.lrr=1e-3", "--set", f"output_dir={tmp / 'runs'}"],
            ["training.lrr", "did you mean 'lr'?", "valid keys in 'training'"],
            [],
        ),
        "a readings CSV separated by semicolons": (
            [
                "record",
                f"video:{f['video']}",
                *("--out", str(tmp / "data"), "--object", "foam", "--modulus", "2e4"),
                *("--readings", str(f["semicolons"])),
            ],
            ["readings-semicolons.csv", "separated by ';', not commas"],
            ["missing column"],
        ),
        "import burgess of a path cut short": (
            ["import", "burgess", str(tmp / "syn"), "--out", str(tmp / "data")],
            ["syn: no such directory", f"did you mean {tmp / 'synthetic'}?"],
            [],
        ),
        "import burgess --fingers markers of a markerless-only tree": (
            [
                *("import", "burgess", str(f["recorded"])),
                *("--out", str(tmp / "data"), "--fingers", "markers"),
            ],
            ["no sample has RGB_markers.pkl", "--fingers markerless"],
            ["missing file"],
        ),
        "frames too small for Top10NN": (
            [
                *("train", "--set", "model.name=top10nn", "--size", "48x48"),
                *("--set", f"output_dir={tmp / 'runs'}"),
            ],
            ["top10nn needs frames of at least 65x65 px", "48x48"],
            [],
        ),
        "train --split that does not exist": (
            ["train", "--split", str(tmp / "split.json"), "--set", f"output_dir={tmp / 'runs'}"],
            ["split.json: no such split file"],
            ["Errno"],
        ),
        "a model name typo": (
            ["train", "--set", "model.name=restf", "--set", f"output_dir={tmp / 'runs'}"],
            ["unknown model 'restf'", "did you mean 'res_tf'?"],
            ["Traceback"],
        ),
        "an input strategy typo": (
            ["train", "--set", "inputs=ImageFx", "--set", f"output_dir={tmp / 'runs'}"],
            ["unknown input strategy 'ImageFx'", "did you mean 'ImageF' or 'ImageFW'?"],
            [],
        ),
        "a preset name typo": (
            ["train", "-c", "defualt", "--set", f"output_dir={tmp / 'runs'}"],
            ["no config file or preset named 'defualt'", "did you mean 'default'?"],
            [],
        ),
        "an experiment name typo": (
            ["experiment", "tabel1", "--out", str(tmp / "runs"), "--results", str(tmp / "results")],
            ["no experiment file or preset named 'tabel1'", "did you mean 'table1'"],
            [],
        ),
    }


CASE_NAMES = list(
    _cases(
        {
            k: Path(k)
            for k in (
                *("store", "onnx", "text", "foreign", "truncated", "video", "tmp"),
                *("recorded", "semicolons"),
            )
        }
    )
)


@pytest.mark.parametrize("label", CASE_NAMES)
def test_a_mistake_gives_one_line_naming_its_cause(label: str, files: dict[str, Path]) -> None:
    args, says, never = _cases(files)[label]
    result = runner.invoke(app, args)
    assert result.exit_code == 2, (label, result.output, result.exception)
    line = _one_error_line(result)
    for text in says:  # a text, or a tuple of wordings of which one must appear
        assert any(t in line for t in ((text,) if isinstance(text, str) else text)), (label, line)
    for text in never:
        assert text not in line, (label, line)
    for name in ("runs", "results", "sim", "data"):  # a failed command creates no folder
        assert not (files["tmp"] / name).exists(), (label, name)


def test_export_without_onnx_says_what_to_install_and_leaves_no_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    for name in ("onnx", "onnxruntime"):
        monkeypatch.setitem(sys.modules, name, None)  # import raises ImportError
    out = tmp_path / "new" / "model.onnx"
    safetensors = tmp_path / "st"
    args = ["export", str(tmp_path / "best.pt"), "--onnx", str(out)]
    result = runner.invoke(app, [*args, "--safetensors", str(safetensors)])
    assert result.exit_code == 2, result.output
    line = _one_error_line(result)
    assert "pip install 'tactile-compliance[export]'" in line and "onnx" in line, line
    assert not (tmp_path / "new").exists() and not safetensors.exists()


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO / "src"), *sys.path])}
    return subprocess.run(
        [sys.executable, *args], capture_output=True, text=True, env=env, timeout=300, check=False
    )


def test_a_missing_camera_prints_one_line_and_no_opencv_warnings(tmp_path: Path) -> None:
    # In a subprocess: OpenCV writes its warnings to file descriptor 2, past sys.stderr.
    result = _run(
        "-m", "tactile_compliance", "calibrate", "camera:7", "--out", str(tmp_path / "c.json")
    )
    assert result.returncode == 2, result
    assert result.stderr.strip().splitlines() == [
        "error: camera 7: cannot open the camera (not connected, in use, or not a format "
        "OpenCV reads)"
    ], result.stderr
    assert not (tmp_path / "c.json").exists()


CHECK_WITHOUT_TORCH = """
import sys
from tactile_compliance.cli import app
from tactile_compliance.data.store import HEADER_FILE
try:
    app(sys.argv[1:], prog_name="tactile-compliance")
except SystemExit as exit:
    print(exit.code, sorted(m for m in ("torch", "lightning") if m in sys.modules))
"""


def test_a_config_typo_is_reported_before_torch_is_imported(tmp_path: Path) -> None:
    """What makes it fast (under 2 s instead of 13-22 s): nothing heavy is imported."""
    for args in (
        ["train", "--set", "training.lrr=1e-3"],
        ["train", "--set", "model.name=restf"],
        ["train", "--set", "inputs=imagefx"],
        ["train", "-c", "defualt"],
        ["train", "--set", "model.name=top10nn", "--size", "48x48"],
        ["import", "burgess", str(tmp_path / "sin"), "--out", str(tmp_path / "store")],
        ["train", "-c", str(tmp_path / "missing.yaml")],
        ["pretrain", str(tmp_path), "--backbone", "resnet18", "--out", "w.pt", "--set", "x=1"],
    ):
        result = _run("-c", CHECK_WITHOUT_TORCH, *args)
        assert result.stdout.strip() == "2 []", (args, result)
        assert len(result.stderr.strip().splitlines()) == 1, (args, result.stderr)


def test_device_auto_is_the_gpu_when_there_is_one_and_cuda_without_one_is_one_line(
    tmp_path: Path,
) -> None:
    from tactile_compliance.devices import resolve_device

    assert resolve_device("auto") == ("cuda" if torch.cuda.is_available() else "cpu")
    assert resolve_device("cpu") == "cpu"
    if torch.cuda.is_available():
        return
    (tmp_path / "best.pt").write_text("not read: the device is checked first")
    result = runner.invoke(
        app, ["predict", str(tmp_path / "best.pt"), str(tmp_path), "--device", "cuda"]
    )
    assert result.exit_code == 2, result.output
    assert "sees no CUDA GPU; use auto or cpu" in _one_error_line(result)


def test_every_device_default_is_the_one_default() -> None:
    """Commands and Python entry points default to one device, ``auto`` (issue 29: it was
    auto in pretrain but cpu in predict and live). Every parameter named ``device`` with a
    default, in every module of the package, takes ``devices.DEFAULT_DEVICE`` (a camera's
    device index aside)."""
    import ast
    import inspect

    from tactile_compliance import devices
    from tactile_compliance.cli.training import DEFAULT_DEVICE
    from tactile_compliance.config import TrainingConfig
    from tactile_compliance.inference import ComplianceEstimator, EnsembleEstimator

    assert DEFAULT_DEVICE == devices.DEFAULT_DEVICE == "auto"
    found = []
    for path in sorted((REPO / "src" / "tactile_compliance").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            args = node.args
            positional = [*args.posonlyargs, *args.args]
            pairs = list(
                zip(positional[len(positional) - len(args.defaults) :], args.defaults, strict=True)
            )
            pairs += [
                (a, d)
                for a, d in zip(args.kwonlyargs, args.kw_defaults, strict=True)
                if d is not None
            ]
            for arg, default in pairs:
                camera = isinstance(default, ast.Constant) and not isinstance(default.value, str)
                if arg.arg == "device" and not camera:  # not a camera's index (sensors.py)
                    found.append(f"{path.name}:{node.name}")
                    assert ast.unparse(default) == "DEFAULT_DEVICE", (path, node.name)
    assert len(found) >= 15, found  # estimators, loaders, predict_path, evaluate_run, cli, ...
    for function in (ComplianceEstimator.from_pretrained, EnsembleEstimator.from_checkpoints):
        assert inspect.signature(function).parameters["device"].default == "auto", function
    assert TrainingConfig().device == "auto"
    for name in ("pretrain", "evaluate", "predict", "live"):
        command = dict(
            (c.name, c)
            for c in typer.main.get_command(app).commands.values()  # type: ignore[attr-defined]
        )[name]
        option = next(p for p in command.params if "--device" in p.opts)
        assert option.default == "auto", name


def test_a_warning_is_one_clean_line_not_the_library_file_that_raised_it(tmp_path: Path) -> None:
    """Issue 42: a config warning showed ``.../pydantic/main.py:792: UserWarning``."""
    result = _run(
        "-c",
        CHECK_WITHOUT_TORCH,
        *("train", "--set", "model.freeze_backbone=true"),
        *("--set", f"data.store={tmp_path / 'missing'}"),
    )
    lines = result.stderr.strip().splitlines()
    assert lines[0].startswith("warning: augmentation.enabled with model.freeze_backbone"), lines
    assert "pydantic" not in result.stderr and "UserWarning" not in result.stderr
    assert lines[-1].startswith("error: ") and len(lines) == 2, lines
