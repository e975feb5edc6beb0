"""Estimate dropout (issue 40: every grasp gets an estimate): a model trained with
``training.estimate_dropout`` sees some grasps' analytical estimates hidden as missing,
so ``predict``, the store path and the stream still estimate a grasp whose fits failed
(NaN estimates), where a model trained without it skips or waits."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
import torch

from helpers import pressed_frames
from tactile_compliance.config import ConfigError, load_config
from tactile_compliance.data.normalisation import MISSING_SCALAR, NormalisationConstants
from tactile_compliance.data.store import ESTIMATE_COLUMNS, SAMPLES_FILE
from tactile_compliance.inference import ComplianceEstimator
from tactile_compliance.inference.predict import predict_path
from tactile_compliance.models import create_model
from tactile_compliance.runs.run_inputs import RunInputs
from tactile_compliance.training.module import ComplianceModule
from tactile_compliance.training.train import train
from toy_store import make_toy_store


@pytest.fixture(scope="module")
def store(tmp_path_factory: pytest.TempPathFactory) -> Any:
    return make_toy_store(tmp_path_factory.mktemp("dropout") / "store", n_objects=8)


@pytest.fixture(scope="module")
def runs(store: Any, tmp_path_factory: pytest.TempPathFactory) -> dict[float, Path]:
    out = tmp_path_factory.mktemp("runs")
    made = {}
    for dropout in (0.0, 0.3):
        overrides = [
            f"data.store={store.path}",
            "inputs=FWE",
            "training.max_epochs=3",
            f"training.estimate_dropout={dropout}",
        ]
        made[dropout] = out / f"FWE-{dropout}"
        train(load_config("default", overrides), run_dir=made[dropout], progress=False)
    return made


def _module(dropout: float, seed: int = 0) -> ComplianceModule:
    model = create_model("scalar_mlp", inputs="FWE")
    run_inputs = RunInputs(
        None, (32, 32), NormalisationConstants(), "FWE", missing_estimates=dropout > 0
    )
    return ComplianceModule(
        model, run_inputs, lr=1e-3, gamma=None, l2_weight=0.0, estimate_dropout=dropout, seed=seed
    )


def test_training_hides_a_share_of_the_estimates_and_leaves_the_batch_alone() -> None:
    n = 4000
    estimates = torch.rand(n, 2) + 0.5  # never MISSING_SCALAR by chance
    force = torch.rand(n, 3)
    batch = {"label": torch.rand(n), "estimates": estimates, "force": force}
    kept = estimates.clone()
    out = _module(0.3)._hide_estimates(batch)
    hidden = (out["estimates"] == MISSING_SCALAR).all(dim=1)
    assert 0.27 < hidden.float().mean() < 0.33
    # Whole pairs are hidden, the other grasps and inputs are untouched.
    assert torch.equal(out["estimates"][~hidden], kept[~hidden])
    assert (out["estimates"][hidden] == MISSING_SCALAR).all() and out["force"] is force
    assert torch.equal(batch["estimates"], kept)  # the cached inputs are not written to
    # The same seed hides the same grasps; another seed others; no dropout hides none.
    again = _module(0.3)._hide_estimates(batch)["estimates"]
    assert torch.equal(again, out["estimates"])
    assert not torch.equal(_module(0.3, seed=1)._hide_estimates(batch)["estimates"], again)
    assert _module(0.0)._hide_estimates(batch) is batch
    # The rate and the checkpoint's promise are one setting.
    model = create_model("scalar_mlp", inputs="FWE")
    plain = RunInputs(None, (32, 32), NormalisationConstants(), "FWE")
    with pytest.raises(ValueError, match="one setting"):
        ComplianceModule(model, plain, lr=1e-3, gamma=None, l2_weight=0.0, estimate_dropout=0.3)


def test_a_resumed_run_hides_the_grasps_an_uninterrupted_one_would() -> None:
    # The resume checkpoint keeps the dropout generator's state (on_save_checkpoint).
    batch = {"label": torch.rand(64), "estimates": torch.rand(64, 2) + 0.5}
    first = _module(0.3)
    first._hide_estimates(batch)  # an epoch or so before the interruption
    checkpoint: dict[str, Any] = {"state_dict": {}}
    first.on_save_checkpoint(checkpoint)
    expected = first._hide_estimates(batch)["estimates"]
    resumed = _module(0.3)
    resumed.on_load_checkpoint(checkpoint)
    assert torch.equal(resumed._hide_estimates(batch)["estimates"], expected)
    # Without the state a fresh module would hide other grasps.
    assert not torch.equal(_module(0.3)._hide_estimates(batch)["estimates"], expected)


def test_the_config_refuses_dropout_for_inputs_without_estimates() -> None:
    with pytest.raises(ConfigError, match="estimate_dropout"):
        load_config("default", ["inputs=FW", "training.estimate_dropout=0.2"])
    with pytest.raises(ConfigError):
        load_config("default", ["inputs=FWE", "training.estimate_dropout=1.0"])


def test_a_dropout_model_predicts_a_grasp_without_estimates(runs) -> None:
    plain = ComplianceEstimator.from_checkpoint(runs[0.0])
    dropout = ComplianceEstimator.from_checkpoint(runs[0.3])
    assert dropout.run_inputs.missing_estimates and not plain.run_inputs.missing_estimates
    force, width = [8.0, 30.0, 58.0], [0.05, 0.047, 0.044]
    missing = dropout.predict(force=force, width=width, estimates=[np.nan, np.nan])
    # Missing is what 1e2 Pa (the clamp floor) normalises to: MISSING_SCALAR.
    floor = dropout.predict(force=force, width=width, estimates=[1e2, 1e2])
    assert np.isfinite(missing.modulus_pa)
    assert missing.log10_modulus_pa == pytest.approx(float(floor.log10_modulus_pa), abs=1e-6)
    one = dropout.predict(force=force, width=width, estimates=[np.nan, 3e5])
    assert np.isfinite(one.modulus_pa)
    with pytest.raises(ValueError, match="NaN/inf"):
        plain.predict(force=force, width=width, estimates=[np.nan, np.nan])
    with pytest.raises(ValueError, match="NaN/inf"):  # infinity is never "missing"
        dropout.predict(force=force, width=width, estimates=[np.inf, 3e5])


def test_the_store_path_predicts_every_grasp_of_a_dropout_model(runs, store, tmp_path) -> None:
    copy = tmp_path / "store"
    shutil.copytree(store.path, copy)
    samples = pd.read_parquet(copy / SAMPLES_FILE)
    samples.loc[: len(samples) // 2, list(ESTIMATE_COLUMNS)] = np.nan  # fits that failed
    samples.to_parquet(copy / SAMPLES_FILE, index=False)
    report = predict_path(runs[0.3], copy)
    assert report["summary"]["n_predicted"] == len(samples) and not report["skipped"]
    plain = predict_path(runs[0.0], copy)
    assert plain["summary"]["n_predicted"] < len(samples)
    assert {s["reason"] for s in plain["skipped"]} == {"missing estimates (NaN)"}


def test_the_stream_gives_a_dropout_model_an_estimate_where_the_fits_fail() -> None:
    frames, force, width = pressed_frames()
    depth = np.zeros((len(force), 60, 80), np.float32)  # no contact: no estimate can be made

    def final(missing_estimates: bool) -> Any:
        torch.manual_seed(0)
        model = create_model("top10nn", inputs="ALL")
        run_inputs = RunInputs(
            (72, 72), (72, 72), NormalisationConstants(), "ALL", missing_estimates=missing_estimates
        )
        stream = ComplianceEstimator(model, run_inputs).stream()
        emitted = [
            stream.update(frames[i], force[i], width[i], depth_mm=depth[i])
            for i in range(len(force))
        ]
        final_estimate = stream.finish()
        return final_estimate, ComplianceEstimator(model, run_inputs), [e for e in emitted if e]

    estimate, estimator, emitted = final(True)
    assert estimate is not None and estimate.final and np.isfinite(estimate.modulus_pa)
    # One estimate per new frame selection: a NaN estimate does not count as a change.
    provisional = [e.frame_indices for e in emitted if not e.final]
    assert provisional and len(provisional) == len(set(provisional))
    idx = list(estimate.frame_indices)
    direct = estimator.predict(
        frames[idx], force=force[idx], width=width[idx], estimates=[np.nan, np.nan]
    )
    assert estimate.modulus_pa == pytest.approx(float(direct.modulus_pa), rel=1e-6)
    assert final(False)[0] is None  # without dropout the stream has nothing to give


def test_the_onnx_export_keeps_taking_missing_estimates(runs, tmp_path) -> None:
    from typer.testing import CliRunner

    from tactile_compliance.cli import app
    from tactile_compliance.inference.onnx import OnnxEstimator

    path = tmp_path / "model.onnx"
    result = CliRunner().invoke(app, ["export", str(runs[0.3]), "--onnx", str(path)])
    assert result.exit_code == 0, result.output
    result = CliRunner().invoke(
        app, ["export", str(runs[0.3]), "--safetensors", str(tmp_path / "st")]
    )
    assert result.exit_code == 0, result.output
    assert "Trained with estimate dropout" in (tmp_path / "st" / "README.md").read_text()
    onnx = OnnxEstimator(path)
    assert onnx.run_inputs.missing_estimates
    given = {"force": [8.0, 30.0, 58.0], "width": [0.05, 0.047, 0.044], "estimates": [np.nan, 2e5]}
    expected = ComplianceEstimator.from_checkpoint(runs[0.3]).predict(**given)
    got = onnx.predict(**given)
    assert float(got.log10_modulus_pa) == pytest.approx(float(expected.log10_modulus_pa), abs=1e-4)
