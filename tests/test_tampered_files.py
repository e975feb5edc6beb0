"""No tampered or damaged file yields a number (issue 30).

Every tampered value of the issue is fed to the three readers of loaded numbers: a
checkpoint (``from_checkpoint``, the ``predict`` command), an ``export --safetensors``
directory (``from_pretrained``, the ``live`` command) and a sensor calibration (``live
--calibration``). Each must fail with one line and a non-zero exit code, and print no
estimate. The intact files predict (the control), so a case fails for its tampering only.
"""

from __future__ import annotations

import base64
import hashlib
import json
import math
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from helpers import make_replay_grasp
from tactile_compliance.acquisition.calibration import SensorCalibration, calibrate
from tactile_compliance.cli import EXIT_BAD_INPUT, app
from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.inference import ComplianceEstimator
from tactile_compliance.inference.export import export_safetensors
from tactile_compliance.inference.pretrained import CONFIG_FILE, WEIGHTS_FILE
from tactile_compliance.models import create_model
from tactile_compliance.runs.checkpoint import save_checkpoint
from tactile_compliance.runs.run_inputs import RunInputs
from toy_store import make_toy_store

pytest.importorskip("safetensors")
runner = CliRunner()
NAN, INF = math.nan, math.inf
DEEP = 100_000  # levels of JSON nesting: beyond Python's recursion limit

# ---------------------------------------------------------------------- the cases
# (case id, the change to the normalisation constants)
CONSTANTS: list[tuple[str, dict[str, Any]]] = [
    ("image_std NaN", {"image_std": [NAN, 0.06, 0.05]}),
    ("image_std 0", {"image_std": [0.0, 0.06, 0.05]}),
    ("image_mean NaN", {"image_mean": [NAN, 0.5, 0.5]}),
    ("image_mean 300", {"image_mean": [300.0, 0.5, 0.5]}),
    ("force_scale_n NaN", {"force_scale_n": NAN}),
    ("force_scale_n inf", {"force_scale_n": INF}),
    ("force_scale_n text", {"force_scale_n": "60"}),
    ("width_scale_m true", {"width_scale_m": True}),
    ("label_log10_max 400", {"label_log10_max": 400.0}),
    ("label_log10_max 30", {"label_log10_max": 30.0}),
    ("label_log10_min NaN", {"label_log10_min": NAN}),
    ("estimate_clamp_pa inf", {"estimate_clamp_pa": [100.0, INF]}),
]


def _first_weight(state: dict[str, torch.Tensor]) -> str:
    return next(k for k, v in state.items() if v.dim() >= 2)


# (case id, a change of the state dict in place)
WEIGHTS: list[tuple[str, Callable[[dict[str, torch.Tensor]], None]]] = [
    ("int8 weights", lambda s: s.update({k: v.to(torch.int8) for k, v in s.items()})),
    ("bool tensor", lambda s: s.update({_first_weight(s): s[_first_weight(s)] > 0})),
    ("NaN weight", lambda s: s[_first_weight(s)].view(-1).__setitem__(0, NAN)),
    ("inf weight", lambda s: s[_first_weight(s)].view(-1).__setitem__(0, INF)),
    ("all-zero weights", lambda s: s.update({k: torch.zeros_like(v) for k, v in s.items()})),
]

# (case id, a change of the description: checkpoint payload or config.json)
META: list[tuple[str, Callable[[dict[str, Any]], None]]] = [
    ("image_size floats", lambda d: d["run_inputs"].update(image_size=[72.7, 72.2])),
    ("image_size negative", lambda d: d["run_inputs"].update(image_size=[-5, 10])),
    ("image_size huge", lambda d: d["run_inputs"].update(image_size=[20000, 20000])),
    ("store_image_size none", lambda d: d["run_inputs"].update(store_image_size=None)),
    ("estimator unknown", lambda d: d["run_inputs"].update(analytical_estimator="hertz")),
    ("run_inputs missing", lambda d: d.pop("run_inputs")),
    ("format_version list", lambda d: d.update(format_version=[1])),
]


# ---------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def files(tmp_path_factory):
    root = tmp_path_factory.mktemp("tampered")
    torch.manual_seed(0)
    model = create_model("top10nn", inputs="Image")
    checkpoint = save_checkpoint(
        root / "best.pt",
        model,
        run_inputs=RunInputs((72, 72), (72, 72), NormalisationConstants(), model.inputs),
        config={},
        seed=0,
    )
    export_safetensors(checkpoint, root / "export")
    grasp = make_replay_grasp(root / "grasp", (60, 84))
    calibrate(f"video:{grasp['still']}", n_frames=5, out=root / "sensor.json")
    store = make_toy_store(root / "store", n_objects=2, grasps=1).path
    return {
        "root": root,
        "checkpoint": checkpoint,
        "export": root / "export",
        "grasp": grasp,
        "calibration": root / "sensor.json",
        "store": store,
    }


def _one_line_failure(result) -> None:
    lines = result.output.strip().splitlines()
    assert result.exit_code == EXIT_BAD_INPUT, result.output
    assert len(lines) == 1 and lines[0].startswith("error: "), result.output
    assert result.exception is None or isinstance(result.exception, SystemExit)
    assert " E = " not in result.output and "Pa (log10" not in result.output


def _predict(files, checkpoint: Path):
    return runner.invoke(app, ["predict", str(checkpoint), str(files["store"])])


def _live(files, model: Path, calibration: Path | None = None):
    grasp = files["grasp"]
    args = ["live", str(model), f"video:{grasp['video']}"]
    args += ["--readings", str(grasp["readings"])]
    args += ["--calibration", str(calibration or files["calibration"])]
    return runner.invoke(app, args)


def test_the_intact_files_give_estimates(files):
    result = _predict(files, files["checkpoint"])
    assert result.exit_code == 0, result.output
    result = _live(files, files["export"])
    assert result.exit_code == 0 and "final       E = " in result.output, result.output


# ---------------------------------------------------------------------- checkpoints
def _tampered_checkpoint(files, name: str, change: Callable[[dict[str, Any]], None]) -> Path:
    payload = torch.load(files["checkpoint"], weights_only=True)
    change(payload)
    path = files["root"] / f"{name.replace(' ', '_')}.pt"
    torch.save(payload, path)
    return path


@pytest.mark.parametrize(("name", "values"), CONSTANTS, ids=[c[0] for c in CONSTANTS])
def test_checkpoint_constants(files, name, values):
    path = _tampered_checkpoint(
        files, name, lambda p: p["run_inputs"]["normalisation"].update(values)
    )
    with pytest.raises(ValueError) as err:
        ComplianceEstimator.from_checkpoint(path)
    assert "\n" not in str(err.value)
    _one_line_failure(_predict(files, path))


@pytest.mark.parametrize(("name", "change"), WEIGHTS, ids=[c[0] for c in WEIGHTS])
def test_checkpoint_weights(files, name, change):
    path = _tampered_checkpoint(files, name, lambda p: change(p["state_dict"]))
    with pytest.raises(ValueError, match="weight"):
        ComplianceEstimator.from_checkpoint(path)
    _one_line_failure(_predict(files, path))


@pytest.mark.parametrize(("name", "change"), META, ids=[c[0] for c in META])
def test_checkpoint_description(files, name, change):
    path = _tampered_checkpoint(files, name, change)
    with pytest.raises(ValueError):
        ComplianceEstimator.from_checkpoint(path)
    _one_line_failure(_predict(files, path))


# ---------------------------------------------------------------------- exports
def _tampered_export(
    files,
    name: str,
    config_change: Callable[[dict[str, Any]], None] | None = None,
    tensor_change: Callable[[dict[str, torch.Tensor]], None] | None = None,
    *,
    rehash: bool = True,
) -> Path:
    """A copy of the export, changed; ``rehash`` records the new weights' sha256 (so the
    check under test is the one that refuses, not the checksum)."""
    import safetensors.torch

    path = files["root"] / f"export-{name.replace(' ', '_')}"
    shutil.copytree(files["export"], path)
    config = json.loads((path / CONFIG_FILE).read_text())
    if tensor_change is not None:
        tensors = safetensors.torch.load_file(str(path / WEIGHTS_FILE))
        tensor_change(tensors)
        safetensors.torch.save_file(tensors, str(path / WEIGHTS_FILE))
        if rehash:
            digest = hashlib.sha256((path / WEIGHTS_FILE).read_bytes()).hexdigest()
            config["weights_sha256"] = digest
    if config_change is not None:
        config_change(config)
    (path / CONFIG_FILE).write_text(json.dumps(config))
    return path


@pytest.mark.parametrize(("name", "values"), CONSTANTS, ids=[c[0] for c in CONSTANTS])
def test_export_constants(files, name, values):
    path = _tampered_export(files, name, lambda c: c["run_inputs"]["normalisation"].update(values))
    with pytest.raises(ValueError) as err:
        ComplianceEstimator.from_pretrained(path)
    assert "\n" not in str(err.value)
    _one_line_failure(_live(files, path))


@pytest.mark.parametrize(("name", "change"), WEIGHTS, ids=[c[0] for c in WEIGHTS])
def test_export_weights(files, name, change):
    path = _tampered_export(files, name, tensor_change=change)
    with pytest.raises(ValueError, match="weight"):
        ComplianceEstimator.from_pretrained(path)
    _one_line_failure(_live(files, path))


def test_export_weights_of_another_export_fail_the_checksum(files):
    def halve(tensors):
        tensors.update({k: v / 2 for k, v in tensors.items()})

    path = _tampered_export(files, "unhashed", tensor_change=halve, rehash=False)
    with pytest.raises(ValueError, match="sha256"):
        ComplianceEstimator.from_pretrained(path)
    _one_line_failure(_live(files, path))


@pytest.mark.parametrize(
    ("name", "change"),
    [
        *META,
        ("no weights_sha256", lambda c: c.pop("weights_sha256")),
        ("hparams text", lambda c: c.update(hparams="{}")),
    ],
    ids=[c[0] for c in META] + ["no weights_sha256", "hparams text"],
)
def test_export_description(files, name, change):
    path = _tampered_export(files, name, change)
    with pytest.raises(ValueError):
        ComplianceEstimator.from_pretrained(path)
    _one_line_failure(_live(files, path))


def test_deeply_nested_json_is_one_line(files):
    path = _tampered_export(files, "deep")
    (path / CONFIG_FILE).write_text('{"a": ' * DEEP + "1" + "}" * DEEP)
    _one_line_failure(_live(files, path))
    calibration = files["root"] / "deep-sensor.json"
    calibration.write_text("[" * DEEP + "]" * DEEP)
    _one_line_failure(_live(files, files["export"], calibration))


# ---------------------------------------------------------------------- calibrations
def _png(image: np.ndarray) -> str:
    return base64.b64encode(cv2.imencode(".png", image)[1].tobytes()).decode("ascii")


def _huge_png_header() -> str:
    """The signature and header of a 20000 x 20000 PNG (the pixels never needed)."""
    import struct
    import zlib

    header = struct.pack(">IIBBBBB", 20000, 20000, 8, 2, 0, 0, 0)
    chunk = b"IHDR" + header
    data = b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + chunk
    data += struct.pack(">I", zlib.crc32(chunk))
    return base64.b64encode(data).decode("ascii")


def _geometry(**changes: Any) -> Callable[[dict[str, Any]], None]:
    return lambda d: d["geometry"].update(changes)


CALIBRATIONS: list[tuple[str, Callable[[dict[str, Any]], None]]] = [
    (
        "grey reference",
        lambda d: d.update(reference_png_base64=_png(np.full((60, 84, 3), 128, np.uint8))),
    ),
    (
        "white reference",
        lambda d: d.update(reference_png_base64=_png(np.full((60, 84, 3), 255, np.uint8))),
    ),
    ("huge reference PNG", lambda d: d.update(reference_png_base64=_huge_png_header())),
    ("output_size huge", _geometry(output_size=[40000, 40000])),
    ("output_size floats", _geometry(output_size=[72.7, 72.2])),
    ("crop_px text", _geometry(crop_px="5")),
    (
        "collinear corners",
        _geometry(warp_corners=[[0, 0], [10, 10], [20, 20], [30, 30]], warp_size=[60, 84]),
    ),
    (
        "corners outside",
        _geometry(warp_corners=[[0, 0], [900, 0], [900, 700], [0, 700]], warp_size=[60, 84]),
    ),
]


@pytest.mark.parametrize(("name", "change"), CALIBRATIONS, ids=[c[0] for c in CALIBRATIONS])
def test_calibration(files, name, change):
    data = json.loads(files["calibration"].read_text())
    change(data)
    path = files["root"] / f"{name.replace(' ', '_')}.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ValueError) as err:
        SensorCalibration.load(path)
    if name == "huge reference PNG":  # refused by its header, before decoding 1.2 GB
        assert "20000x20000 px is out of range" in str(err.value)
    _one_line_failure(_live(files, files["export"], path))


# ---------------------------------------------------------------------- stores
STORE_HEADERS: list[tuple[str, Callable[[dict[str, Any]], None]]] = [
    ("image_size swapped", lambda h: h.update(image_size=h["image_size"][::-1])),
    ("image_size floats", lambda h: h.update(image_size=[72.7, 72.2])),
    ("image_size negative", lambda h: h.update(image_size=[-5, 10])),
    ("format_version list", lambda h: h.update(format_version=[1])),
    ("num_samples text", lambda h: h.update(num_samples="10")),
]


@pytest.mark.parametrize(("name", "change"), STORE_HEADERS, ids=[c[0] for c in STORE_HEADERS])
def test_store_header(files, tmp_path, name, change):
    store = make_toy_store(tmp_path / "store", n_objects=2, grasps=1, size=(32, 48))
    header = json.loads((store.path / "header.json").read_text())
    change(header)
    (store.path / "header.json").write_text(json.dumps(header))
    result = runner.invoke(app, ["info", str(store.path)])
    _one_line_failure(result)
    if name == "image_size swapped":  # the same byte count: only the checksum tells
        assert "frame_shape_sha256 differs" in result.output
    _one_line_failure(runner.invoke(app, ["predict", str(files["checkpoint"]), str(store.path)]))


def test_store_header_nested_too_deeply(tmp_path):
    store = make_toy_store(tmp_path / "store", n_objects=2, grasps=1)
    (store.path / "header.json").write_text('{"a": ' * DEEP + "1" + "}" * DEEP)
    _one_line_failure(runner.invoke(app, ["info", str(store.path)]))


def test_a_model_that_outputs_nan_gives_no_estimate(files, monkeypatch):
    """The last line of defence, should a broken model pass every check."""
    estimator = ComplianceEstimator.from_checkpoint(files["checkpoint"])
    monkeypatch.setattr(estimator.model, "forward", lambda *a, **k: torch.full((1,), NAN))
    frames = np.full((3, 72, 72, 3), 0.5, np.float32)
    with pytest.raises(ValueError, match="non-finite output"):
        estimator.predict(frames)
