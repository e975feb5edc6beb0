"""`sim2real`: synthetic grasps of a real rig -> one model that `predict` takes."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
from typer.testing import CliRunner

from helpers import cli, json_lines, make_replay_grasp
from tactile_compliance.cli import app
from tactile_compliance.data.store import GraspStore
from tactile_compliance.outputs import OutputExistsError
from tactile_compliance.sim2real import run_sim2real
from tactile_compliance.synthetic.rig import RIGS

runner = CliRunner()


@pytest.fixture(scope="module")
def sim2real_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("sim2real") / "out"
    result = runner.invoke(app, ["sim2real", "--out", str(out), "--mode", "ci", "--json"])
    assert result.exit_code == 0, result.output
    summary = json.loads(result.stdout)
    assert summary["checkpoint"] == str(out / "best.pt") and summary["rig"] == "wedge-2023"
    assert set(summary["stage_seconds"]) == {"generate", "import", "train"}
    assert not (out / "run" / "checkpoints").exists()  # only best.pt is kept
    return out


def test_the_data_comes_from_the_rig_and_the_model_from_the_preset(sim2real_dir: Path) -> None:
    generation = json.loads((sim2real_dir / "raw" / "generation.json").read_text())
    assert generation["options"]["rig"] == RIGS["wedge-2023"].to_dict()
    assert GraspStore.open(sim2real_dir / "store").forces_n().max() < 35.0  # not ~60 N
    meta = torch.load(sim2real_dir / "best.pt", map_location="cpu", weights_only=False)
    assert meta["model_name"] == "vgg_lstm" and meta["config"]["model"]["freeze_backbone"]
    assert meta["run_inputs"]["inputs"] == "ALL"
    assert meta["run_inputs"]["image_size"] == [32, 32]
    assert meta["config"]["data"]["fingers"] == ["markerless"]


def test_predict_takes_the_model(sim2real_dir: Path) -> None:
    result = runner.invoke(
        app, ["predict", str(sim2real_dir / "best.pt"), str(sim2real_dir / "store"), "--json"]
    )
    assert result.exit_code == 0, result.output
    predictions = json.loads(result.stdout)
    assert predictions["summary"]["n_predicted"] > 0
    assert all(p["pred_pa"] > 0 for p in predictions["predictions"])


def test_rerunning_continues_and_foreign_folders_are_refused(
    sim2real_dir: Path, tmp_path: Path
) -> None:
    before = (sim2real_dir / "best.pt").stat().st_mtime_ns
    summary = run_sim2real(sim2real_dir, mode="ci", progress=False)
    assert summary.stage_seconds["generate"] < 5.0  # every object was already there
    assert (sim2real_dir / "best.pt").stat().st_mtime_ns >= before
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("keep me")
    with pytest.raises(OutputExistsError):
        run_sim2real(foreign, mode="ci", progress=False)
    assert (foreign / "notes.txt").read_text() == "keep me"


def test_live_gives_the_estimate_that_record_and_predict_give(
    sim2real_dir: Path, tmp_path: Path
) -> None:
    """The preset's model (frozen VGG16 features, ALL inputs) through the user path on a
    recorded video: `live` recomputes the features and the estimates that `record` stored."""

    grasp = make_replay_grasp(tmp_path / "grasp", (250, 350))  # the estimators need this size
    model = sim2real_dir / "best.pt"
    sensor, data, store = tmp_path / "sensor.json", tmp_path / "data", tmp_path / "store"
    common = ["--readings", grasp["readings"], "--calibration", sensor]
    cli("calibrate", f"video:{grasp['still']}", "--out", sensor, "--frames", 5)
    label = ["--object", grasp["name"], "--modulus", grasp["modulus_pa"]]
    cli("record", f"video:{grasp['video']}", "--out", data, *label, *common)
    cli("import", "burgess", data, "--out", store, "--fingers", "markerless")
    predicted = json.loads(cli("predict", model, store, "--json"))
    first = next(p for p in predicted["predictions"] if p["augmentation"] == 0)
    events = json_lines(cli("live", model, f"video:{grasp['video']}", *common, "--json"))
    assert events[-1]["final"]
    assert events[-1]["log10_modulus_pa"] == pytest.approx(first["pred_log10_pa"], abs=1e-5)


def test_the_summary_warns_when_the_model_learned_nothing() -> None:
    from tactile_compliance.sim2real import MIN_SYNTHETIC_R2, Sim2RealSummary

    def summary(r2: float, mode: str = "full") -> str:
        test = {"nmse": 0.08, "r2": r2, "log10_accuracy": 0.1}
        return Sim2RealSummary(
            Path("o"), Path("o/best.pt"), "wedge-2023", mode, {"train": 1.0}, test
        ).format()

    assert "Warning" in summary(MIN_SYNTHETIC_R2 - 0.01) and "--seed" in summary(-0.05)
    assert "Warning" not in summary(0.25) and "R^2 0.25" in summary(0.25)
    assert "Warning" not in summary(-0.05, mode="ci")  # a tiny run is not meant to learn
