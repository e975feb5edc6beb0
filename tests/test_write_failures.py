"""Full disks, huge sizes and interrupted writes end in one line, never a traceback, and
leave the previous output intact (issue 30).

A full disk is simulated as torch's zip writer reports it (``RuntimeError`` with the
``OSError(ENOSPC)`` as its context) or as a plain ``OSError(ENOSPC)``. Exit code 1 for
a full disk in every command (the input was fine), 2 for bad input.
"""

from __future__ import annotations

import errno
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from tactile_compliance.cli import EXIT_BAD_INPUT, EXIT_FAILED, app
from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.inference import ComplianceEstimator, pretrained
from tactile_compliance.inference.pretrained import CONFIG_FILE, WEIGHTS_FILE
from tactile_compliance.models import create_model
from tactile_compliance.outputs import MARKER_NAME
from tactile_compliance.runs.checkpoint import save_checkpoint
from tactile_compliance.runs.run_inputs import RunInputs
from toy_store import depth_toy_store, make_toy_store

runner = CliRunner()


def _one_line(result, code: int) -> str:
    """The error (one line; a configuration's errors list one per line below it)."""
    lines = result.output.strip().splitlines()
    assert result.exit_code == code, result.output
    errors = [line for line in lines if line.startswith("error: ")]
    assert len(errors) == 1, result.output
    assert "Traceback" not in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    return result.output[result.output.index("error: ") :]


def _checkpoint(path: Path, seed: int = 0, model: str = "top10nn") -> Path:
    torch.manual_seed(seed)
    return save_checkpoint(
        path,
        create_model(model, inputs="Image"),
        run_inputs=RunInputs((72, 72), (72, 72), NormalisationConstants(), "Image"),
        config={},
        seed=seed,
    )


def _torch_full_disk(*args, **kwargs):
    """What torch.save raises when the disk fills up under it."""
    try:
        raise OSError(errno.ENOSPC, "No space left on device")
    except OSError:
        raise RuntimeError(
            "[enforce fail at inline_container.cc:672] . unexpected pos 704"
        ) from None


# ---------------------------------------------------------------------- export
def test_export_replaces_weights_and_config_together(tmp_path, monkeypatch):
    first, second = _checkpoint(tmp_path / "a.pt", 0), _checkpoint(tmp_path / "b.pt", 1)
    out = tmp_path / "export"
    assert runner.invoke(app, ["export", str(first), "--safetensors", str(out)]).exit_code == 0
    (out / "notes.txt").write_text("mine")
    before = {p.name: p.read_bytes() for p in out.iterdir()}

    # Killed at the moment of the swap: the old pair is whole, nothing is left beside it.
    def killed(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(pretrained, "exchange_directories", killed)
    with pytest.raises(KeyboardInterrupt):
        pretrained.write_pretrained(
            ComplianceEstimator.from_checkpoint(second), out, checkpoint=second
        )
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.pt", "b.pt", "export"]
    monkeypatch.undo()

    result = runner.invoke(app, ["export", str(second), "--safetensors", str(out)])
    assert result.exit_code == 0, result.output
    config = json.loads((out / CONFIG_FILE).read_text())
    assert config["checkpoint"]["file"] == "b.pt"
    assert (out / WEIGHTS_FILE).read_bytes() != before[WEIGHTS_FILE]
    assert (out / "notes.txt").read_text() == "mine"  # the user's file is kept
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.pt", "b.pt", "export"]
    ComplianceEstimator.from_pretrained(out)


def test_export_of_a_full_disk_is_one_line_and_leaves_nothing(tmp_path, monkeypatch):
    checkpoint = _checkpoint(tmp_path / "a.pt")

    def full(tensors, path, metadata=None):
        Path(path).write_bytes(b"")
        raise OSError(errno.ENOSPC, "No space left on device", path)

    import safetensors.torch

    monkeypatch.setattr(safetensors.torch, "save_file", full)
    result = runner.invoke(app, ["export", str(checkpoint), "--safetensors", str(tmp_path / "e")])
    assert "No space left" in _one_line(result, EXIT_FAILED)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.pt"]


def test_export_of_a_missing_checkpoint_creates_nothing(tmp_path):
    out = tmp_path / "deep" / "e3"
    args = ["export", str(tmp_path / "nonexist"), "--safetensors", str(out)]
    _one_line(runner.invoke(app, args), EXIT_BAD_INPUT)
    assert not (tmp_path / "deep").exists()


# ---------------------------------------------------------------------- train, pretrain
def test_train_on_a_full_disk_is_one_line_with_exit_code_1(tmp_path, monkeypatch):
    store = make_toy_store(tmp_path / "store", n_objects=6, grasps=2)
    monkeypatch.setattr(torch, "save", _torch_full_disk)
    args = ["train", "--set", f"data.store={store.path}", "--set", "data.image_size=[72,72]"]
    args += ["--set", "training.max_epochs=1", "--out", str(tmp_path / "run")]
    assert "No space left on device" in _one_line(runner.invoke(app, args), EXIT_FAILED)


def test_a_huge_image_size_is_refused_before_a_run_directory_exists(tmp_path):
    args = ["train", "--set", f"data.store={tmp_path}", "--set", "data.image_size=[20000,20000]"]
    args += ["--out", str(tmp_path / "run")]
    assert "out of range" in _one_line(runner.invoke(app, args), EXIT_BAD_INPUT)
    assert not (tmp_path / "run").exists()


@pytest.fixture(scope="module")
def depth_store(tmp_path_factory):
    return depth_toy_store(tmp_path_factory.mktemp("depth") / "store", n_objects=6, grasps=2)


def _pretrain(store, out: Path, *extra: str):
    args = ["pretrain", str(store.path), "--backbone", "top10nn-cnn", "--out", str(out)]
    return runner.invoke(app, [*args, "--epochs", "1", *extra])


def test_pretrain_on_a_full_disk_is_one_line(depth_store, tmp_path, monkeypatch):
    monkeypatch.setattr(torch, "save", _torch_full_disk)
    result = _pretrain(depth_store, tmp_path / "bb.pt", "--size", "72x72")
    assert "No space left on device" in _one_line(result, EXIT_FAILED)
    assert not list(tmp_path.iterdir())


def test_pretrain_refuses_frames_its_backbone_cannot_take(depth_store, tmp_path):
    result = _pretrain(depth_store, tmp_path / "bb.pt", "--size", "32x32")
    assert "at least 65x65 px" in _one_line(result, EXIT_BAD_INPUT)


def test_a_truncated_pretrain_state_is_set_aside_as_corrupt(depth_store, tmp_path):
    out = tmp_path / "bb.pt"
    state = tmp_path / "bb.pt.pretrain-state.pt"
    torch.save({"kind": "tactile-compliance-pretrain-state", "x": torch.zeros(5000)}, state)
    state.write_bytes(state.read_bytes()[:3000])  # a crash mid-write
    with pytest.warns(UserWarning, match="corrupt"):
        result = _pretrain(depth_store, out, "--size", "72x72")
    assert result.exit_code == 0, result.output
    assert out.is_file() and (tmp_path / "bb.pt.pretrain-state.pt.corrupt").is_file()
    # A file that is not a torch archive is someone else's: refused, not moved.
    state.write_text("my notes")
    result = _pretrain(depth_store, out, "--size", "72x72", "--overwrite")
    _one_line(result, EXIT_BAD_INPUT)
    assert state.read_text() == "my notes"


# ---------------------------------------------------------------------- sizes
@pytest.mark.parametrize("size", ["30000x30000", "100000x100000"])
def test_huge_sizes_are_refused_before_allocating(tmp_path, size):
    frames = tmp_path / "frames"
    frames.mkdir()
    import cv2

    for i in range(3):
        cv2.imwrite(str(frames / f"{i}.png"), np.full((20, 30, 3), 100 + 20 * i, np.uint8))
    calibration = tmp_path / "c.json"
    args = ["calibrate", f"folder:{frames}", "--fps", "10", "--out", str(calibration)]
    args = [*args, "--size", size]
    yuan = ["import", "yuan", str(tmp_path), "--out", str(tmp_path / "s"), "--size", size]
    for result in (runner.invoke(app, args), runner.invoke(app, yuan)):
        # A bad option value: click's usage error (exit 2), no traceback, no allocation.
        assert result.exit_code == EXIT_BAD_INPUT, result.output
        assert "out of range" in result.output
        assert result.exception is None or isinstance(result.exception, SystemExit)
    assert not calibration.exists() and not (tmp_path / "s").exists()


@pytest.mark.parametrize(
    ("corners", "message"),
    [
        ("0,0 10,10 20,20 29,19", "convex quadrilateral"),
        ("0,0 500,0 500,400 0,400", "outside the 20x30 px camera frame"),
    ],
)
def test_calibrate_refuses_degenerate_corners(tmp_path, corners, message):
    import cv2

    frames = tmp_path / "frames"
    frames.mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):
        cv2.imwrite(str(frames / f"{i}.png"), rng.integers(0, 255, (20, 30, 3), np.uint8))
    out = tmp_path / "c.json"
    args = ["calibrate", f"folder:{frames}", "--fps", "10", "--out", str(out), "--frames", "3"]
    args += ["--corners", corners, "--warp-size", "16x24"]
    assert message in _one_line(runner.invoke(app, args), EXIT_BAD_INPUT)
    assert not out.exists()
    assert MARKER_NAME  # (outputs' marker untouched: a calibration is a single file)
