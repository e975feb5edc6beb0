"""Deployable weights: `export --safetensors DIR` -> `ComplianceEstimator.from_pretrained(DIR)`.

The reference is always ``ComplianceEstimator.from_checkpoint`` on the same checkpoint and
inputs; the card is checked against the run's own ``metrics.json``.
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

pytest.importorskip("safetensors")

from safetensors.torch import load_file

from tactile_compliance.cli import app
from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.inference import ComplianceEstimator
from tactile_compliance.inference.export import export_safetensors
from tactile_compliance.inference.pretrained import (
    CARD_FILE,
    CONFIG_FILE,
    WEIGHTS_FILE,
    SafetensorsMissingError,
    pretrained_config,
)
from tactile_compliance.outputs import OutputExistsError
from tactile_compliance.runs.checkpoint import (
    FROZEN_BACKBONE_SEED,
    create_seeded_model,
    frozen_backbone_record,
    save_checkpoint,
)
from tactile_compliance.runs.run_inputs import RunInputs
from tactile_compliance.training.train import train
from toy_store import make_toy_store, tiny_run_config

runner = CliRunner()
SMALL_RES_TF = {"num_layers": 1, "embedding_dim": 64, "output_dim": 64}


@pytest.fixture(scope="module")
def top10nn_run(tmp_path_factory) -> Path:
    """A one-epoch Top10NN run (ALL inputs) on the toy store: a real run directory."""
    root = tmp_path_factory.mktemp("pretrained")
    store = make_toy_store(root / "store", n_objects=12, grasps=3)
    cfg = tiny_run_config(
        store.path,
        root / "runs",
        "top10nn",
        ["inputs=ALL", "data.image_size=[72,72]", "training.max_epochs=1", "training.lr=1e-3"],
    )
    return root / "runs" / train(cfg, progress=False)["run_name"]


@pytest.fixture(scope="module")
def res_tf_head_only(tmp_path_factory) -> Path:
    """A head-only checkpoint of a frozen-backbone Res-Tf (as training writes one)."""
    import torch

    model = create_seeded_model("res_tf", FROZEN_BACKBONE_SEED, inputs="ImageF", **SMALL_RES_TF)
    generator = torch.Generator().manual_seed(2)
    with torch.no_grad():  # a head unlike any initialisation, as training leaves it
        for name, parameter in model.named_parameters():
            if not name.startswith("backbone."):
                parameter.add_(0.05 * torch.randn(parameter.shape, generator=generator))
    record = frozen_backbone_record(model, seed=FROZEN_BACKBONE_SEED)
    return save_checkpoint(
        tmp_path_factory.mktemp("res_tf") / "best.pt",
        model.eval(),
        run_inputs=RunInputs((32, 32), (32, 32), NormalisationConstants(), model.inputs),
        config={"seed": 3},
        seed=3,
        frozen_backbone=record,
    )


def _inputs(batch: int = 5, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    return {
        "frames": rng.integers(80, 180, size=(batch, 3, 36, 44, 3), dtype=np.uint8),
        "force": rng.uniform(5, 60, (batch, 3)),
        "width": rng.uniform(0.03, 0.06, (batch, 3)),
        "estimates": 10 ** rng.uniform(3, 9, (batch, 2)),
    }


def _predict(estimator: ComplianceEstimator, inputs: dict) -> np.ndarray:
    return estimator.predict(**{k: inputs[k] for k in estimator.required_inputs}).log10_modulus_pa


@pytest.mark.parametrize("which", ["top10nn_run", "res_tf_head_only"])
def test_from_pretrained_reproduces_from_checkpoint(request, tmp_path, which):
    checkpoint = request.getfixturevalue(which)
    report = export_safetensors(checkpoint, tmp_path / "model")
    assert sorted(report["files"]) == sorted([WEIGHTS_FILE, CONFIG_FILE, CARD_FILE])
    reference = ComplianceEstimator.from_checkpoint(checkpoint)
    loaded = ComplianceEstimator.from_pretrained(tmp_path / "model")
    inputs = _inputs()
    expected = _predict(reference, inputs)
    assert np.ptp(expected) > 1e-3  # the inputs matter, so equal outputs mean equal models
    np.testing.assert_allclose(_predict(loaded, inputs), expected, rtol=0, atol=1e-5)
    assert loaded.run_inputs == reference.run_inputs
    # Self-contained: the weights file holds the whole state dict, a frozen backbone too.
    stored = load_file(str(tmp_path / "model" / WEIGHTS_FILE))
    assert set(stored) == set(reference.model.state_dict())
    assert any(k.startswith("backbone.") for k in stored)


def test_card_holds_the_runs_metrics_strategy_and_data(tmp_path, top10nn_run):
    export_safetensors(top10nn_run, tmp_path / "model")
    card = (tmp_path / "model" / CARD_FILE).read_text()
    result = json.loads((top10nn_run / "metrics.json").read_text())
    config = json.loads((tmp_path / "model" / CONFIG_FILE).read_text())
    # The card formats numbers with 4 significant digits.
    test_row = next(line for line in card.splitlines() if line.startswith("| model, test split"))
    for name in ("log10_accuracy", "nmse", "r2", "mae_decades", "within_half_decade"):
        assert f"{result['test'][name]:.4g}" in test_row, name
    assert f"| {result['test']['n']} |" in test_row
    assert f"**{result['inputs']}**" in card
    assert f"condition **{result['condition']}**" in card
    height, width = result["image_size"]
    assert f"{height} x {width} px" in card
    assert str(config["run_inputs"]["normalisation"]["image_mean"]) in card
    assert "source `toy`" in card  # the training store's provenance, from the checkpoint
    assert config["training_store"]["source"] == "toy"
    assert config["evaluation"]["test"] == result["test"]


def test_config_json_round_trips(tmp_path, top10nn_run):
    export_safetensors(top10nn_run, tmp_path / "model")
    written = json.loads((tmp_path / "model" / CONFIG_FILE).read_text())
    checkpoint = ComplianceEstimator.from_checkpoint(top10nn_run)
    assert written["model_name"] == "top10nn" and written["run_inputs"]["inputs"] == "ALL"
    assert written["run_inputs"] == checkpoint.run_inputs.to_dict()
    assert written["hparams"] == checkpoint.meta["hparams"]
    loaded = ComplianceEstimator.from_pretrained(tmp_path / "model")
    assert loaded.run_inputs == checkpoint.run_inputs
    # Loaded -> described again: the same config (the weights' hash is added on writing).
    again = pretrained_config(
        loaded, checkpoint=top10nn_run / "best.pt", evaluation=written["evaluation"]
    )
    assert again == {k: v for k, v in written.items() if k != "weights_sha256"}


def test_export_never_overwrites_a_users_directory(tmp_path, top10nn_run):
    user = tmp_path / "mine"
    user.mkdir()
    (user / "notes.txt").write_text("mine")
    with pytest.raises(OutputExistsError):
        export_safetensors(top10nn_run, user)
    assert [p.name for p in user.iterdir()] == ["notes.txt"]
    assert (user / "notes.txt").read_text() == "mine"
    # Its own output is replaced on re-export.
    export_safetensors(top10nn_run, tmp_path / "model")
    export_safetensors(top10nn_run, tmp_path / "model")
    result = runner.invoke(app, ["export", str(top10nn_run), "--safetensors", str(user)])
    assert result.exit_code == 2 and "error:" in result.output
    assert [p.name for p in user.iterdir()] == ["notes.txt"]


def test_cli_writes_both_formats_and_needs_one(tmp_path, top10nn_run):
    pytest.importorskip("onnxruntime")
    args = ["export", str(top10nn_run), "--safetensors", str(tmp_path / "st")]
    result = runner.invoke(app, [*args, "--onnx", str(tmp_path / "m.onnx")])
    assert result.exit_code == 0, result.output
    assert (tmp_path / "st" / WEIGHTS_FILE).is_file() and (tmp_path / "m.onnx").is_file()
    result = runner.invoke(app, ["export", str(top10nn_run)])
    assert result.exit_code == 2 and "--safetensors" in result.output


def test_load_tells_an_export_from_a_checkpoint(tmp_path, top10nn_run):
    """`ComplianceEstimator.load` (what `predict` and `live` use): a directory holding
    model.safetensors is an export, a run directory a checkpoint; both give one model."""
    export_safetensors(top10nn_run, tmp_path / "model")
    exported = ComplianceEstimator.load(tmp_path / "model")
    checkpoint = ComplianceEstimator.load(top10nn_run)
    assert exported.source == str(tmp_path / "model")
    assert checkpoint.source.endswith("best.pt")
    inputs = _inputs()
    np.testing.assert_allclose(
        _predict(exported, inputs), _predict(checkpoint, inputs), rtol=0, atol=1e-5
    )


def test_from_pretrained_errors(tmp_path, top10nn_run, monkeypatch):
    export_safetensors(top10nn_run, tmp_path / "model")
    model = tmp_path / "model"
    with pytest.raises(FileNotFoundError, match="no such directory"):
        ComplianceEstimator.from_pretrained(tmp_path / "nowhere")
    broken = tmp_path / "broken"
    broken.mkdir()
    (broken / CONFIG_FILE).write_text((model / CONFIG_FILE).read_text())
    with pytest.raises(FileNotFoundError, match=WEIGHTS_FILE):
        ComplianceEstimator.from_pretrained(broken)
    # Weights that do not fit the config's hyperparameters.
    config = json.loads((model / CONFIG_FILE).read_text())
    config["hparams"]["img_feature_size"] = 64
    (broken / CONFIG_FILE).write_text(json.dumps(config))
    (broken / WEIGHTS_FILE).write_bytes((model / WEIGHTS_FILE).read_bytes())
    with pytest.raises(ValueError, match="do not fit 'top10nn'"):
        ComplianceEstimator.from_pretrained(broken)
    (broken / WEIGHTS_FILE).write_bytes(b"not safetensors")
    with pytest.raises(ValueError, match=r"sha256 .* is not the .* that config\.json records"):
        ComplianceEstimator.from_pretrained(broken)
    config["weights_sha256"] = hashlib.sha256(b"not safetensors").hexdigest()
    (broken / CONFIG_FILE).write_text(json.dumps(config))
    with pytest.raises(ValueError, match="not a readable safetensors file"):
        ComplianceEstimator.from_pretrained(broken)
    # No safetensors package: a clear error, also from the CLI (one line, exit 2).
    monkeypatch.setitem(sys.modules, "safetensors", None)
    monkeypatch.setitem(sys.modules, "safetensors.torch", None)
    with pytest.raises(SafetensorsMissingError, match="pip install"):
        ComplianceEstimator.from_pretrained(model)
    result = runner.invoke(app, ["export", str(top10nn_run), "--safetensors", str(tmp_path / "x")])
    assert result.exit_code == 2 and "safetensors is not installed" in result.output
    assert not (tmp_path / "x").exists()  # nothing written before the check


@pytest.mark.slow
def test_frozen_vgg_lstm_export_is_self_contained(tmp_path):
    # VGG16 (138 M parameters): the head-only checkpoint is small, the export holds it all.
    model = create_seeded_model("vgg_lstm", FROZEN_BACKBONE_SEED, inputs="ALL", hidden_size=32)
    record = frozen_backbone_record(model, seed=FROZEN_BACKBONE_SEED)
    checkpoint = save_checkpoint(
        tmp_path / "best.pt",
        model.eval(),
        run_inputs=RunInputs((32, 32), (32, 32), NormalisationConstants(), model.inputs),
        config={},
        seed=0,
        frozen_backbone=record,
    )
    export_safetensors(checkpoint, tmp_path / "model")
    size = (tmp_path / "model" / WEIGHTS_FILE).stat().st_size
    assert size > 20 * checkpoint.stat().st_size  # the backbone's tensors are in it
    inputs = _inputs(batch=2)
    expected = _predict(ComplianceEstimator.from_checkpoint(checkpoint), inputs)
    loaded = ComplianceEstimator.from_pretrained(tmp_path / "model")
    np.testing.assert_allclose(_predict(loaded, inputs), expected, rtol=0, atol=1e-5)


def test_the_units_of_the_estimates_travel_into_the_export(tmp_path):
    """A model trained on a calibrated sensor's estimates says so in config.json, and
    `from_pretrained` reads it back (live compares it with the sensor's calibration)."""
    import torch

    from tactile_compliance.models import create_model
    from tactile_compliance.physics.estimators import SensorUnits

    torch.manual_seed(0)
    units = {"depth_model": "calibrated", "px_per_mm": 12.5}
    save_checkpoint(
        tmp_path / "best.pt",
        create_model("top10nn", inputs="ALL"),
        run_inputs=RunInputs(
            (72, 72), (72, 72), NormalisationConstants(), "ALL", sensor=SensorUnits(**units)
        ),
        config={},
        seed=0,
    )
    assert ComplianceEstimator.from_checkpoint(tmp_path / "best.pt").run_inputs.sensor == (
        SensorUnits("calibrated", 12.5)
    )
    export_safetensors(tmp_path / "best.pt", tmp_path / "model")
    config = json.loads((tmp_path / "model" / CONFIG_FILE).read_text())
    assert config["run_inputs"]["sensor"] == units
    loaded = ComplianceEstimator.from_pretrained(tmp_path / "model")
    assert loaded.run_inputs.sensor == SensorUnits("calibrated", 12.5)
    assert loaded.run_inputs.estimator.px_per_mm == 12.5


def _strings(value) -> list[str]:  # type: ignore[no-untyped-def]
    if isinstance(value, dict):
        return [s for item in value.values() for s in _strings(item)]
    if isinstance(value, list):
        return [s for item in value for s in _strings(item)]
    return [value] if isinstance(value, str) else []


def test_an_export_holds_no_local_path_and_a_licence(tmp_path, top10nn_run):
    runner.invoke(app, ["export", str(top10nn_run), "--safetensors", str(tmp_path / "m")])
    config = json.loads((tmp_path / "m" / CONFIG_FILE).read_text())
    card = (tmp_path / "m" / CARD_FILE).read_text()
    # The run and its store lie under the test's temporary folder: no path to it is kept.
    root = str(top10nn_run.parents[1])
    assert not [s for s in _strings(config) if s.startswith("/")], config
    assert root not in json.dumps(config) and root not in card
    assert config["training_store"]["path"] == "store"  # the store's folder name
    assert config["license"] == "other" and "\nlicense: other\n" in card
    result = runner.invoke(
        app, ["export", str(top10nn_run), "--safetensors", str(tmp_path / "m"), "--license", "mit"]
    )
    assert result.exit_code == 0, result.output
    assert "\nlicense: mit\n" in (tmp_path / "m" / CARD_FILE).read_text()


def test_save_pretrained_writes_what_from_pretrained_loads(tmp_path, top10nn_run):
    reference = ComplianceEstimator.from_checkpoint(top10nn_run)
    report = reference.save_pretrained(tmp_path / "saved", license="cc-by-4.0")
    assert sorted(report["files"]) == sorted([WEIGHTS_FILE, CONFIG_FILE, CARD_FILE])
    loaded = ComplianceEstimator.from_pretrained(tmp_path / "saved")
    inputs = _inputs()
    np.testing.assert_allclose(
        _predict(loaded, inputs), _predict(reference, inputs), rtol=0, atol=1e-5
    )
    card = (tmp_path / "saved" / CARD_FILE).read_text()
    assert "\nlicense: cc-by-4.0\n" in card and "| model, test split" in card  # run metrics
    # From a loaded export too, and never into a folder of someone's files.
    loaded.save_pretrained(tmp_path / "again")
    assert ComplianceEstimator.from_pretrained(tmp_path / "again").inputs == reference.inputs
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    with pytest.raises(OutputExistsError):
        reference.save_pretrained(mine)
    assert [p.name for p in mine.iterdir()] == ["notes.txt"]


def test_export_json_says_what_was_written(tmp_path, top10nn_run):
    args = ["export", str(top10nn_run), "--safetensors", str(tmp_path / "m"), "--json"]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    written = json.loads(result.output)["safetensors"]
    assert written["out"] == str(tmp_path / "m")
    assert written["files"][WEIGHTS_FILE] == (tmp_path / "m" / WEIGHTS_FILE).stat().st_size
