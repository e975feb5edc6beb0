"""The strategies beyond the paper (FW, FWE, DepthFW, FWR) through every surface: train, the
estimator API, ONNX, safetensors, ``predict`` and ``live`` (docs/models.md, "Input
strategies")."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
import torch
from typer.testing import CliRunner

from tactile_compliance.cli import app
from tactile_compliance.config import load_config
from tactile_compliance.data.inputs import INPUTS, InputStrategy
from tactile_compliance.inference import ComplianceEstimator
from tactile_compliance.synthetic.rig import DATASET_RIG
from tactile_compliance.training.train import train
from toy_store import make_toy_store

STRATEGIES = ("FW", "FWE", "DepthFW", "FWR")
#: The toy store's rig: the dataset rig's stiffness, so `estimate --rig dataset` makes the
#: rig-corrected estimates an FWR model trained on it takes (the replayed grasp's own rig).
RIG_STIFFNESS_N_PER_M = DATASET_RIG.stiffness_n_per_m


@pytest.fixture(scope="module")
def store(tmp_path_factory: pytest.TempPathFactory) -> Any:
    return make_toy_store(
        tmp_path_factory.mktemp("depth") / "store",
        n_objects=8,
        depth=True,
        units={"rig_stiffness_n_per_m": RIG_STIFFNESS_N_PER_M},
    )


@pytest.fixture(scope="module")
def runs(store: Any, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # small runs: one thread is faster; restored for later tests
    out = tmp_path_factory.mktemp("runs")
    made = {}
    for inputs in STRATEGIES:
        overrides = [
            f"data.store={store.path}",
            f"output_dir={out}",
            f"inputs={inputs}",
            "training.max_epochs=3",
            "training.batch_size=16",
        ]
        if inputs == "DepthFW":  # Top10NN needs 65 px; the toy depth maps are 8x8
            overrides += ["data.image_size=[72,72]", "training.lr=1e-3"]
        made[inputs] = out / inputs
        train(load_config("default", overrides), run_dir=made[inputs], progress=False)
    torch.set_num_threads(threads)
    return made


def test_a_frame_free_strategy_trains_the_frame_free_model_without_naming_it(runs) -> None:
    for inputs in ("FW", "FWE", "FWR"):
        config = json.loads((runs[inputs] / "metrics.json").read_text())
        assert config["model"] == "scalar_mlp", config
        assert config["image_size"] is None
    depth = json.loads((runs["DepthFW"] / "metrics.json").read_text())
    assert depth["model"] == "top10nn" and depth["image_size"] == [72, 72]


def _given(store: Any, ids: np.ndarray) -> dict[str, Any]:
    """Every input of the table for store rows ``ids``, in physical units."""
    rows = store.samples.iloc[ids]
    given: dict[str, Any] = {"frames": store.read_samples(ids), "depth": store.read_depth(ids)}
    for spec in INPUTS.values():
        if spec.kind == "scalar":
            given[spec.name] = rows[list(spec.columns)].to_numpy(np.float64)
    return given


@pytest.mark.parametrize("inputs", STRATEGIES)
def test_predict_needs_only_the_strategy_inputs_and_names_a_missing_one(
    runs, store, inputs: str
) -> None:
    estimator = ComplianceEstimator.from_checkpoint(runs[inputs])
    strategy = InputStrategy.parse(inputs)
    ids = np.arange(6)
    given = _given(store, ids)
    needed = {name: given[name] for name in strategy.input_names}
    assert estimator.required_inputs == strategy.input_names
    result = estimator.predict(**needed)
    assert result.modulus_pa.shape == (6,) and np.all(np.isfinite(result.modulus_pa))
    # The other inputs change nothing, and are not even validated.
    junk = {n: "junk" for n in INPUTS if n not in strategy.input_names}
    np.testing.assert_array_equal(estimator.predict(**needed, **junk).modulus_pa, result.modulus_pa)
    # One grasp unbatched gives the same value as in the batch.
    single = estimator.predict(**{n: v[2] for n, v in needed.items()})
    assert single.modulus_pa == pytest.approx(float(result.modulus_pa[2]), rel=1e-5)
    for name in strategy.input_names:
        with pytest.raises(ValueError, match=f"needs `{name}` \\("):
            estimator.predict(**{n: v for n, v in needed.items() if n != name})


def test_the_predictions_are_the_runs_own(runs, store) -> None:
    # predict on the store gives what train wrote for its test split.
    for inputs in STRATEGIES:
        frame = pd.read_csv(runs[inputs] / "predictions.csv")
        test = frame[frame["split"] == "test"]
        estimator = ComplianceEstimator.from_checkpoint(runs[inputs])
        ids = test["sample_id"].to_numpy()
        needed = _given(store, ids)
        got = estimator.predict(**{n: needed[n] for n in estimator.required_inputs})
        np.testing.assert_allclose(
            got.log10_modulus_pa, np.log10(test["pred_pa"].to_numpy()), atol=1e-5
        )


@pytest.mark.parametrize("inputs", STRATEGIES)
def test_onnx_safetensors_and_predict_agree(runs, store, tmp_path, inputs: str) -> None:
    runner = CliRunner()
    onnx_path = tmp_path / "model.onnx"
    result = runner.invoke(app, ["export", str(runs[inputs]), "--onnx", str(onnx_path)])
    assert result.exit_code == 0, result.output
    result = runner.invoke(
        app, ["export", str(runs[inputs]), "--safetensors", str(tmp_path / "st")]
    )
    assert result.exit_code == 0, result.output
    from tactile_compliance.inference.onnx import OnnxEstimator

    torch_estimator = ComplianceEstimator.from_checkpoint(runs[inputs])
    onnx_estimator = OnnxEstimator(onnx_path)
    pretrained = ComplianceEstimator.from_pretrained(tmp_path / "st")
    strategy = InputStrategy.parse(inputs)
    assert onnx_estimator.input_names == list(strategy.input_names)
    given = _given(store, np.arange(5))
    needed = {n: given[n] for n in strategy.input_names}
    expected = torch_estimator.predict(**needed).log10_modulus_pa
    onnx_log10 = onnx_estimator.predict(**needed).log10_modulus_pa
    np.testing.assert_allclose(onnx_log10, expected, atol=1e-4)
    np.testing.assert_array_equal(pretrained.predict(**needed).log10_modulus_pa, expected)
    card = (tmp_path / "st" / "README.md").read_text()
    assert f"**{inputs}**" in card and "predict(" + strategy.input_names[0] in card
    assert ("N/m (`record --rig`)" in card) == (inputs == "FWR")

    # `predict` reads the store's inputs, depth maps included.
    result = runner.invoke(app, ["predict", str(runs[inputs]), str(store.path), "--json"])
    assert result.exit_code == 0, result.output
    report = json.loads(result.output)
    assert report["summary"]["n_predicted"] == len(store)


def _readings_csv(path: Path) -> Path:
    """A grasp's readings: the force rises to 30 N and falls, the width closes."""
    times = np.arange(40) / 30.0
    force = np.concatenate([np.linspace(0, 30, 25), np.linspace(30, 2, 15)])
    width = 0.05 - 0.01 * force / 30
    pd.DataFrame({"timestamp_s": times, "force_n": force, "width_m": width}).to_csv(
        path, index=False
    )
    return path


def test_live_runs_a_frame_free_model_on_readings_alone(runs, tmp_path) -> None:
    csv = _readings_csv(tmp_path / "readings.csv")
    result = CliRunner().invoke(
        app, ["live", str(runs["FW"]), "none", "--readings", str(csv), "--json"]
    )
    assert result.exit_code == 0, result.output
    events = [json.loads(line) for line in result.output.splitlines() if line.startswith("{")]
    final = [e for e in events if e.get("final")]
    assert len(final) == 1 and np.isfinite(final[0]["modulus_pa"])
    # The same three readings through the estimator give the same value.
    estimator = ComplianceEstimator.from_checkpoint(runs["FW"])
    direct = estimator.predict(force=final[0]["force_n"], width=final[0]["width_m"])
    assert final[0]["modulus_pa"] == pytest.approx(direct.modulus_pa, rel=1e-6)


@pytest.mark.parametrize(
    ("inputs", "cause"),
    [
        ("DepthFW", "reads depth, but the source `none` gives no camera"),
        ("FWE", "depth maps"),
        ("FWR", "depth maps"),
    ],
)
def test_live_none_with_a_model_that_needs_frames_says_why_in_one_line(
    runs, tmp_path, inputs: str, cause: str
) -> None:
    csv = _readings_csv(tmp_path / "readings.csv")
    result = CliRunner().invoke(app, ["live", str(runs[inputs]), "none", "--readings", str(csv)])
    assert result.exit_code != 0
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and cause in lines[0], result.output


def test_a_grid_over_inputs_gives_each_strategy_its_model(tmp_path: Path) -> None:
    from tactile_compliance.training.experiment_file import expand_experiment, load_experiment

    grid = tmp_path / "grid.yaml"
    grid.write_text("config: default\ngrid:\n  inputs: [ALL, FW, FWE, DepthFW]\nseeds: [0]\n")
    cells = expand_experiment(load_experiment(grid), store=tmp_path / "store")
    chosen = {c.cfg.inputs: (c.cfg.model.name, c.cfg.training.lr) for c in cells}
    assert chosen == {
        "ALL": ("top10nn", 3e-6),
        "FW": ("scalar_mlp", 1e-3),
        "FWE": ("scalar_mlp", 1e-3),
        "DepthFW": ("top10nn", 3e-6),
    }
    # A model named in the grid stays named.
    grid.write_text(
        "config: default\nset:\n  model.name: res_tf\ngrid:\n  inputs: [ALL, DepthALL]\n"
    )
    cells = expand_experiment(load_experiment(grid), store=tmp_path / "store")
    assert {c.cfg.model.name for c in cells} == {"res_tf"}


def test_tune_searches_the_frame_free_model() -> None:
    from tactile_compliance.training import hpo

    space = hpo.search_space("scalar_mlp", "FW", seed=0)
    assert {"model.hparams.hidden_sizes", "model.hparams.dropout", "training.lr"} <= set(
        space.keys()
    )


def _live_and_estimate(
    run: Path, tmp_path: Path, *estimate_options: str
) -> tuple[dict[str, Any], dict[str, Any]]:
    """`live RUN` on a replayed synthetic grasp (its final event) and `estimate` with
    ``estimate_options`` on the same recording (its JSON)."""
    from helpers import make_replay_grasp as make_grasp  # a replayable synthetic grasp

    grasp = make_grasp(tmp_path / "grasp", (250, 350))  # the dataset's estimator's frame size
    source = ["video:" + str(grasp["video"]), "--readings", str(grasp["readings"]), "--json"]
    result = CliRunner().invoke(app, ["live", str(run), *source])
    assert result.exit_code == 0, result.output
    events = [json.loads(line) for line in result.output.splitlines() if line.startswith("{")]
    final = events[-1]
    assert final["final"] and np.isfinite(final["modulus_pa"])
    result = CliRunner().invoke(app, ["estimate", *source, *estimate_options])
    assert result.exit_code == 0, result.output
    return final, json.loads(result.output)


def test_live_runs_a_frame_free_estimates_model_on_a_camera(runs, tmp_path) -> None:
    """FWE with a camera: live takes force and width from the readings and the analytical
    estimates from the video's depth maps, the ones `estimate` prints for the same grasp."""
    final, analytical = _live_and_estimate(runs["FWE"], tmp_path)
    assert analytical["frame_indices"] == final["frame_indices"]
    estimator = ComplianceEstimator.from_checkpoint(runs["FWE"])
    direct = estimator.predict(
        force=final["force_n"], width=final["width_m"], estimates=analytical["estimates_pa"]
    )
    assert final["log10_modulus_pa"] == pytest.approx(float(direct.log10_modulus_pa), abs=1e-6)
    # Without the estimates the same model says which input is missing.
    with pytest.raises(ValueError, match="needs `estimates`"):
        estimator.predict(force=final["force_n"], width=final["width_m"])


def test_a_depth_model_trains_on_cached_frozen_features(store, tmp_path) -> None:
    # The head learns from the depth maps' cached features; the estimator, which runs the
    # rebuilt backbone on the depth maps, gives what the run predicted from the cache.
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        overrides = [
            f"data.store={store.path}",
            f"output_dir={tmp_path}",
            "inputs=DepthFW",
            "model.freeze_backbone=true",
            "augmentation.enabled=false",
            "training.max_epochs=2",
            "training.batch_size=16",
            "data.image_size=[72,72]",
            "training.lr=1e-3",
        ]
        run = tmp_path / "frozen"
        train(load_config("default", overrides), run_dir=run, progress=False)
    finally:
        torch.set_num_threads(threads)
    (cache,) = (store.path / "features").iterdir()
    assert "-depth-" in cache.name
    assert json.loads((cache / "meta.json").read_text())["image"] == "depth"
    test = pd.read_csv(run / "predictions.csv").query("split == 'test'")
    ids = test["sample_id"].to_numpy()
    given = _given(store, ids)
    estimator = ComplianceEstimator.from_checkpoint(run)
    got = estimator.predict(**{n: given[n] for n in estimator.required_inputs})
    # float16 features in training, float32 ones here
    np.testing.assert_allclose(got.log10_modulus_pa, np.log10(test["pred_pa"]), atol=2e-3)


def test_fwr_carries_the_stores_rig_stiffness_and_refuses_a_store_without_one(
    runs, tmp_path
) -> None:
    estimator = ComplianceEstimator.from_checkpoint(runs["FWR"])
    assert estimator.run_inputs.rig_stiffness_n_per_m == pytest.approx(RIG_STIFFNESS_N_PER_M)
    # Strategies without the rig-corrected estimates carry no stiffness.
    assert ComplianceEstimator.from_checkpoint(runs["FWE"]).run_inputs.rig_stiffness_n_per_m is None
    plain = make_toy_store(tmp_path / "plain", n_objects=4, grasps=2)
    overrides = [f"data.store={plain.path}", "inputs=FWR", "training.max_epochs=1"]
    with pytest.raises(Exception, match=r"rig_estimates|rig-corrected"):
        train(load_config("default", overrides), run_dir=tmp_path / "run", progress=False)


def test_live_runs_an_fwr_model_on_a_camera_with_the_checkpoints_rig(runs, tmp_path) -> None:
    """FWR with a camera: live computes the rig-corrected estimates from the video's depth
    maps at the checkpoint's rig stiffness, the ones `estimate --rig` prints for that rig."""
    final, analytical = _live_and_estimate(runs["FWR"], tmp_path, "--rig", "dataset")
    assert analytical["frame_indices"] == final["frame_indices"]
    assert analytical["rig_corrected_pa"] != analytical["estimates_pa"]
    estimator = ComplianceEstimator.from_checkpoint(runs["FWR"])
    direct = estimator.predict(
        force=final["force_n"], width=final["width_m"], rig_estimates=analytical["rig_corrected_pa"]
    )
    assert final["log10_modulus_pa"] == pytest.approx(float(direct.log10_modulus_pa), abs=1e-6)
    # The dataset's estimates in their place give another value: the input is the rig's.
    other = estimator.predict(
        force=final["force_n"], width=final["width_m"], rig_estimates=analytical["estimates_pa"]
    )
    assert float(other.log10_modulus_pa) != pytest.approx(final["log10_modulus_pa"], abs=1e-4)


def test_predict_warns_when_the_stores_rig_is_not_the_models(runs, store, tmp_path) -> None:
    from tactile_compliance.inference.predict import predict_path

    assert not any("N/m" in w for w in predict_path(runs["FWR"], store.path)["warnings"])

    other = make_toy_store(
        tmp_path / "other", n_objects=3, grasps=1, units={"rig_stiffness_n_per_m": 1234.0}
    )
    report = predict_path(runs["FWR"], other.path)
    assert report["summary"]["n_predicted"] == len(other)
    assert any("at 1234 N/m: another rig" in w for w in report["warnings"]), report["warnings"]
    # A store without rig-corrected estimates: every grasp skipped, and the refusal names
    # the strategies that could predict it.
    plain = make_toy_store(tmp_path / "plain", n_objects=3, grasps=1)
    with pytest.raises(ValueError, match="missing rig_estimates"):
        predict_path(runs["FWR"], plain.path)
