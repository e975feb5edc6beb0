"""`adapt`: an output calibration fitted on reference grasps, applied inside the estimator."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from tactile_compliance.cli import app
from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.inference.adapt import (
    GraspPrediction,
    adapt_model,
    leave_one_object_out,
    score_grasps,
)
from tactile_compliance.inference.estimator import ComplianceEstimator
from tactile_compliance.models import create_model
from tactile_compliance.outputs import OutputExistsError
from tactile_compliance.runs.checkpoint import save_checkpoint
from tactile_compliance.runs.output_calibration import (
    OutputCalibration,
    fit_output_calibration,
)
from tactile_compliance.runs.run_inputs import RunInputs

runner = CliRunner()


def test_the_calibration_recovers_a_shift_and_pulls_the_slope_towards_one() -> None:
    rng = np.random.default_rng(0)
    true = rng.uniform(4, 10, 40)
    # A simulation-trained model that ranks right but reads 2.5 decades too stiff.
    pred = true + 2.5 + rng.normal(0, 0.1, true.size)
    cal = fit_output_calibration(pred, true, ridge=0.0)
    assert cal.slope == pytest.approx(1.0, abs=0.02)
    assert np.abs(cal.apply_log10(pred) - true).max() < 0.4
    # Compressed predictions (slope 0.3): unregularised it stretches them, a large ridge
    # keeps the slope near 1 and fits the shift, infinite ridge is the shift alone.
    squeezed = 7 + 0.3 * (true - 7)
    assert fit_output_calibration(squeezed, true, ridge=0.0).slope == pytest.approx(1 / 0.3)
    assert 1.0 < fit_output_calibration(squeezed, true, ridge=100.0).slope < 1.05
    shift = fit_output_calibration(squeezed, true, ridge=math.inf)
    assert shift.slope == 1.0 and shift.intercept == pytest.approx(np.mean(true - squeezed))
    # Monotone: an anti-correlated model gets a flat map, never a reversed ranking.
    assert fit_output_calibration(-true, true, ridge=0.0).slope == 0.0
    with pytest.raises(ValueError, match="no finite"):
        fit_output_calibration([math.nan], [5.0])
    with pytest.raises(ValueError, match="slope must be >= 0"):
        OutputCalibration(0.0, -1.0)
    constants = NormalisationConstants()
    y = np.array([0.2, 0.5, 0.9], dtype=np.float32)
    back = cal.apply_normalised(y, constants) * constants.label_log10_span
    expected = cal.apply_log10(y * constants.label_log10_span + constants.label_log10_min)
    np.testing.assert_allclose(back + constants.label_log10_min, expected, rtol=1e-5)


def test_leave_one_object_out_never_sees_the_object_it_scores() -> None:
    grasps = [
        GraspPrediction(f"obj{i}", g, 10.0 ** (4 + i), 4 + i + 3.0 + 0.05 * g)
        for i in range(5)
        for g in range(3)
    ]
    loo = leave_one_object_out(grasps, ridge=1.0)
    true = [math.log10(g.true_pa) for g in grasps]
    objects = [g.object for g in grasps]
    assert score_grasps(true, [g.pred_log10 for g in grasps], objects)["within_one_decade"] == 0
    scores = score_grasps(true, loo, objects)
    assert scores["within_one_decade"] == 1.0
    assert scores["spearman_objects"] == pytest.approx(1.0)
    # One object alone: nothing to calibrate it on.
    assert math.isnan(leave_one_object_out(grasps[:3], ridge=1.0)[0])


@pytest.fixture(scope="module")
def model_and_store(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    from toy_store import make_toy_store

    tmp = tmp_path_factory.mktemp("adapt")
    make_toy_store(tmp / "store", n_objects=5, grasps=3, size=(32, 32))
    torch.manual_seed(0)
    model = create_model("top10nn", inputs="ImageFW")
    checkpoint = save_checkpoint(
        tmp / "model.pt",
        model,
        run_inputs=RunInputs((72, 72), (32, 32), NormalisationConstants(), "ImageFW"),
        config={},
        seed=0,
    )
    return checkpoint, tmp / "store"


def test_adapt_writes_a_checkpoint_that_predict_loads_with_the_calibration(
    model_and_store: tuple[Path, Path], tmp_path: Path
) -> None:
    checkpoint, store = model_and_store
    start = time.perf_counter()
    result = runner.invoke(
        app, ["adapt", str(checkpoint), str(store), "--out", str(tmp_path / "a"), "--json"]
    )
    assert result.exit_code == 0, result.output
    assert time.perf_counter() - start < 120  # the brief: under 2 minutes on 2 cores
    summary = json.loads(result.stdout)
    assert set(summary["scores"]) == {
        "model",
        "adapted_in_sample",
        "adapted_leave_one_object_out",
    }
    assert summary["calibration"]["fitted_on"]["grasps"] == 15
    assert (
        json.loads((tmp_path / "a" / "adapt.json").read_text())["calibration"]
        == (summary["calibration"])
    )
    adapted = ComplianceEstimator.load(tmp_path / "a", device="cpu")  # what live loads
    original = ComplianceEstimator.load(checkpoint, device="cpu")
    assert original.calibration is None and adapted.calibration is not None
    assert adapted.describe()["output_calibration"]["slope"] == summary["calibration"]["slope"]
    before = json.loads(
        runner.invoke(app, ["predict", str(checkpoint), str(store), "--json"]).stdout
    )
    after = json.loads(
        runner.invoke(
            app, ["predict", str(tmp_path / "a" / "best.pt"), str(store), "--json"]
        ).stdout
    )
    old = np.array([p["pred_log10_pa"] for p in before["predictions"]])
    new = np.array([p["pred_log10_pa"] for p in after["predictions"]])
    np.testing.assert_allclose(new, adapted.calibration.apply_log10(old), atol=1e-4)
    # The calibrated model's mean is the reference objects' mean log10 E (fitted on them).
    truth = np.log10([p["true_pa"] for p in after["predictions"] if p["augmentation"] == 0])
    assert abs(np.mean(new) - np.mean(truth)) < 0.5
    # Re-adapting the adapted model fits on the model's own outputs: the same map.
    again = adapt_model(tmp_path / "a", store, tmp_path / "b", device="cpu")
    assert again.calibration.intercept == pytest.approx(adapted.calibration.intercept)
    assert "leave-one-object-out" in again.format()


def test_adapt_refuses_a_directory_it_did_not_write(
    model_and_store: tuple[Path, Path], tmp_path: Path
) -> None:
    checkpoint, store = model_and_store
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("keep")
    with pytest.raises(OutputExistsError):
        adapt_model(checkpoint, store, tmp_path / "mine", device="cpu")
    assert (tmp_path / "mine" / "notes.txt").read_text() == "keep"


def test_an_adapted_checkpoint_is_not_exported_without_its_calibration(
    model_and_store: tuple[Path, Path], tmp_path: Path
) -> None:
    checkpoint, store = model_and_store
    adapt_model(checkpoint, store, tmp_path / "a", device="cpu")
    args = ["export", str(tmp_path / "a" / "best.pt"), "--safetensors", str(tmp_path / "st")]
    result = runner.invoke(app, args)
    assert result.exit_code == 2 and "adapted checkpoint" in result.output
