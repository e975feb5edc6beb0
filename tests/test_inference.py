"""Inference API: round trip against the evaluation path, input validation, predict_path.

Streaming and ensembles are in ``test_inference_streaming.py``; ONNX in ``test_export.py``.
Trained runs are tiny (one or two epochs on the toy store) and trained once per module.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import replace

import cv2
import numpy as np
import pandas as pd
import pytest
import torch
from typer.testing import CliRunner

from burgess_tree import write_tree
from tactile_compliance.cli import app
from tactile_compliance.config import load_config
from tactile_compliance.data.burgess import import_burgess
from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.data.splits import Split
from tactile_compliance.data.store import (
    ESTIMATE_COLUMNS,
    FORCE_COLUMNS,
    WIDTH_COLUMNS,
    frames_from_uint8,
)
from tactile_compliance.evaluation.evaluate import evaluate_run
from tactile_compliance.inference import (
    ComplianceEstimator,
    EnsembleEstimator,
    Prediction,
    format_predictions,
    predict_path,
)
from tactile_compliance.inference.ensemble import ensemble_calibration
from tactile_compliance.models import create_model
from tactile_compliance.runs.run_inputs import RunInputs
from tactile_compliance.training.train import train
from toy_store import make_toy_store

RUNS = {
    # Top10NN end to end with every input; Res-Tf image-only on cached frozen features
    # (two seeds sharing one split, for the ensemble calibration).
    "top10nn_all": [
        "model.name=top10nn",
        "inputs=ALL",
        "data.image_size=[72,72]",
        "training.max_epochs=1",
        "training.lr=1e-3",
    ],
    "res_tf_image_s0": [
        "model.name=res_tf",
        "inputs=Image",
        "data.image_size=[32,32]",
        "model.freeze_backbone=true",
        "training.max_epochs=1",
        "seed=0",
        "model.hparams={num_layers: 1, embedding_dim: 64, output_dim: 64}",
    ],
    "res_tf_image_s1": [
        "model.name=res_tf",
        "inputs=Image",
        "data.image_size=[32,32]",
        "model.freeze_backbone=true",
        "training.max_epochs=1",
        "seed=1",
        "model.hparams={num_layers: 1, embedding_dim: 64, output_dim: 64}",
    ],
}


@pytest.fixture(scope="module")
def toy_store(tmp_path_factory):
    return make_toy_store(tmp_path_factory.mktemp("inference") / "store", n_objects=12, grasps=3)


@pytest.fixture(scope="module")
def runs(toy_store, tmp_path_factory):
    out = tmp_path_factory.mktemp("runs")
    dirs = {}
    for key, overrides in RUNS.items():
        cfg = load_config(
            "default",
            [
                f"data.store={toy_store.path}",
                f"output_dir={out}",
                "augmentation.enabled=false",
                "training.batch_size=16",
                "split.seed=0",  # every run shares one split (ensemble calibration)
                "training.device=cpu",  # predictions.csv is compared at CPU round-off
                *overrides,
            ],
        )
        dirs[key] = out / train(cfg, progress=False)["run_name"]
    return dirs


def _store_inputs(store, ids):
    rows = store.samples.iloc[ids]
    return {
        "force": rows[list(FORCE_COLUMNS)].to_numpy(),
        "width": rows[list(WIDTH_COLUMNS)].to_numpy(),
        "estimates": rows[list(ESTIMATE_COLUMNS)].to_numpy(),
    }


# ---------------------------------------------------------------------- round trip
@pytest.mark.parametrize("key", ["top10nn_all", "res_tf_image_s0"])
def test_round_trip_matches_evaluation_path(runs, toy_store, key):
    run_dir = runs[key]
    # CPU: the tolerances below are CPU round-off; a GPU's TF32 convolutions differ by
    # ~1e-4 decades (test_cuda.py holds the GPU to its own tolerance).
    evaluation = evaluate_run(run_dir, device="cpu")
    ids = evaluation.predictions["sample_id"].to_numpy()
    estimator = ComplianceEstimator.from_checkpoint(run_dir / "best.pt", device="cpu")
    # An odd batch size: chunking must not change the result.
    prediction = estimator.predict(
        toy_store.frames[ids], **_store_inputs(toy_store, ids), batch_size=5
    )
    expected = np.log10(evaluation.predictions["pred_pa"].to_numpy())
    # Tolerances in decades; the spread of the predictions is far larger, so a wrong
    # preprocessing step (or sample order) cannot pass.
    assert np.ptp(expected) > 1e-3
    # Same path, other batch sizes: only float round-off of batched kernels differs.
    np.testing.assert_allclose(prediction.log10_modulus_pa, expected, atol=1e-5, rtol=0)
    # ... and the numbers the training run itself wrote for its test split (with a frozen
    # backbone those came from the feature cache, computed in other batches).
    written = pd.read_csv(run_dir / "predictions.csv")
    written = written[written["split"] == "test"].set_index("sample_id").loc[ids, "pred_pa"]
    np.testing.assert_allclose(
        prediction.log10_modulus_pa, np.log10(written.to_numpy()), atol=2e-4, rtol=0
    )


def test_single_grasp_gives_floats_equal_to_its_batch_row(runs, toy_store):
    estimator = ComplianceEstimator.from_checkpoint(runs["top10nn_all"])  # a run dir works
    ids = np.arange(4)
    inputs = _store_inputs(toy_store, ids)
    batch = estimator.predict(toy_store.frames[ids], **inputs)
    single = estimator.predict(toy_store.frames[2], **{k: v[2] for k, v in inputs.items()})
    assert isinstance(single.modulus_pa, float) and not single.batched and batch.batched
    # float32 kernels sum in another order for a batch of 1 than of 4 (1.2e-6 relative
    # measured on this VM, 5e-7 decades): far below any real difference, which is decades.
    assert single.modulus_pa == pytest.approx(batch.modulus_pa[2], rel=1e-5)
    assert single.log10_modulus_pa == pytest.approx(np.log10(single.modulus_pa))
    json.dumps(single.to_dict())
    json.dumps(batch.to_dict())


def test_float_frames_bgr_and_lists_give_the_same_estimate(runs, toy_store):
    # CPU: the inputs' forms must agree to 1e-6, finer than a GPU's TF32 convolutions.
    estimator = ComplianceEstimator.from_checkpoint(runs["top10nn_all"], device="cpu")
    inputs = {k: v[0] for k, v in _store_inputs(toy_store, [0]).items()}
    frames = np.array(toy_store.frames[0])
    reference = estimator.predict(frames, **inputs).modulus_pa
    as_float = estimator.predict(frames_from_uint8(frames), **inputs).modulus_pa
    as_bgr = estimator.predict(frames[..., ::-1], channel_order="BGR", **inputs).modulus_pa
    as_lists = estimator.predict(
        torch.from_numpy(frames), **{k: v.tolist() for k, v in inputs.items()}
    ).modulus_pa
    assert as_float == pytest.approx(reference, rel=1e-6)
    assert as_bgr == pytest.approx(reference, rel=1e-6)
    assert as_lists == pytest.approx(reference, rel=1e-6)
    # The channel order matters (otherwise the BGR check above proves nothing).
    assert estimator.predict(frames[..., ::-1], **inputs).modulus_pa != pytest.approx(
        reference, rel=1e-6
    )


def test_inputs_the_strategy_does_not_use_are_ignored(runs, toy_store):
    estimator = ComplianceEstimator.from_checkpoint(runs["res_tf_image_s0"])
    assert estimator.required_inputs == ("frames",)
    frames = toy_store.frames[:2]
    plain = estimator.predict(frames).modulus_pa
    with_junk = estimator.predict(frames, force=[[np.nan] * 3] * 2, width="junk").modulus_pa
    np.testing.assert_array_equal(plain, with_junk)


# ---------------------------------------------------------------------- bad input
@pytest.fixture(scope="module")
def estimator_all():
    torch.manual_seed(0)
    model = create_model("top10nn", inputs="ALL")
    return ComplianceEstimator(
        model, RunInputs((72, 72), (72, 72), NormalisationConstants(), model.inputs)
    )


_RNG = np.random.default_rng(0)
GOOD = {
    "frames": _RNG.integers(100, 156, size=(3, 40, 48, 3), dtype=np.uint8),
    "force": [8.0, 30.0, 58.0],
    "width": [0.050, 0.048, 0.046],
    "estimates": [2e5, 4e5],
}


def _frames_with_nan():
    frames = GOOD["frames"].astype(np.float32) / 255
    frames[1, 3, 4, 0] = np.nan
    return frames


BAD_INPUTS = {
    "frames None": ({"frames": None}, r"needs `frames` \(three difference images"),
    "frames 2-D": ({"frames": np.zeros((40, 48), np.uint8)}, r"frames must have shape"),
    "two frames": ({"frames": GOOD["frames"][:2]}, r"frames must have shape"),
    "four channels": ({"frames": np.zeros((3, 40, 48, 4), np.uint8)}, r"frames must have shape"),
    "channels first": ({"frames": np.zeros((3, 3, 40, 48), np.uint8)}, r"frames must have shape"),
    "int32 frames": ({"frames": GOOD["frames"].astype(np.int32)}, r"uint8 .* got dtype int32"),
    "bool frames": ({"frames": GOOD["frames"] > 128}, r"got dtype bool"),
    "0..255 floats": ({"frames": GOOD["frames"].astype(np.float32)}, r"in \[0, 1\]"),
    "normalised frames": ({"frames": _RNG.standard_normal((3, 40, 48, 3))}, r"in \[0, 1\]"),
    "NaN frame": ({"frames": _frames_with_nan()}, r"NaN"),
    "string frames": ({"frames": "frames.png"}, r"frames must have shape"),
    "empty batch": ({"frames": np.zeros((0, 3, 40, 48, 3), np.uint8)}, r"empty batch"),
    "missing force": ({"force": None}, r"needs `force` \(normal force"),
    "missing width": ({"width": None}, r"needs `width` \(gripper width"),
    "missing estimates": ({"estimates": None}, r"needs `estimates`"),
    "force two values": ({"force": [8.0, 30.0]}, r"`force` .* must have shape \(3,\)"),
    "force scalar": ({"force": 30.0}, r"`force` .* got a scalar"),
    "force NaN": ({"force": [8.0, np.nan, 58.0]}, r"`force` .*NaN"),
    "force negative": ({"force": [-3.0, 30.0, 58.0]}, r"`force` .* must be >= 0"),
    "force text": ({"force": ["a", "b", "c"]}, r"`force` .* must be numeric"),
    "width in mm": ({"width": [50.0, 48.0, 46.0]}, r"`width` .* metres, not millimetres"),
    "width inf": ({"width": [0.05, np.inf, 0.04]}, r"`width` .*NaN/inf"),
    "estimates three values": ({"estimates": [1e5, 2e5, 3e5]}, r"`estimates` .* \(2,\)"),
    "estimates NaN": ({"estimates": [np.nan, 2e5]}, r"`estimates` .*NaN"),
    "batch mismatch": (
        {
            "frames": np.stack([GOOD["frames"]] * 2),
            "force": [[8.0, 30.0, 58.0]] * 3,
            "width": [[0.05, 0.048, 0.046]] * 2,
            "estimates": [[2e5, 4e5]] * 2,
        },
        r"`force` .* must have shape \(2, 3\)",
    ),
    "batch frames, single force": (
        {"frames": np.stack([GOOD["frames"]] * 2)},
        r"`force` .* must have shape \(2, 3\)",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_INPUTS))
def test_bad_input_raises_a_clear_value_error(estimator_all, case):
    changes, message = BAD_INPUTS[case]
    kwargs = {**GOOD, **changes}
    with pytest.raises(ValueError, match=message):
        estimator_all.predict(**kwargs)


def test_good_input_passes_and_bad_options_are_rejected(estimator_all):
    assert np.isfinite(estimator_all.predict(**GOOD).modulus_pa)
    with pytest.raises(ValueError, match="channel_order"):
        estimator_all.predict(**GOOD, channel_order="XYZ")
    with pytest.raises(ValueError, match="batch_size"):
        estimator_all.predict(**GOOD, batch_size=0)


def test_a_resizing_checkpoint_still_rejects_frames_too_small_to_hold_a_contact(estimator_all):
    # Frames are resized to the checkpoint's size, but a 1x1 "frame" is a wrong array.
    from tactile_compliance.data.inputs import MIN_FRAME_SIDE_PX

    assert estimator_all.run_inputs.image_size == (72, 72)
    side = MIN_FRAME_SIDE_PX
    for tiny in ((1, 1), (side - 1, 40), (40, side - 1)):
        with pytest.raises(ValueError, match=rf"at least {side}x{side}"):
            estimator_all.predict(**{**GOOD, "frames": np.full((3, *tiny, 3), 128, np.uint8)})
    frames = np.full((3, side, side, 3), 128, np.uint8)
    assert np.isfinite(estimator_all.predict(**{**GOOD, "frames": frames}).modulus_pa)


def test_loading_a_missing_or_foreign_checkpoint_fails_clearly(tmp_path):
    with pytest.raises(FileNotFoundError):
        ComplianceEstimator.from_checkpoint(tmp_path / "nope.pt")
    with pytest.raises(FileNotFoundError, match=r"best\.pt"):
        ComplianceEstimator.from_checkpoint(tmp_path)
    foreign = tmp_path / "foreign.pt"
    torch.save({"weights": torch.zeros(3)}, foreign)
    with pytest.raises(ValueError, match="not a tactile-compliance"):
        ComplianceEstimator.from_checkpoint(foreign)


# ---------------------------------------------------------------------- predict_path
def test_predict_path_on_a_store_matches_predict_and_is_json(runs, toy_store):
    report = predict_path(runs["top10nn_all"], toy_store.path, batch_size=16)
    json.dumps(report)
    assert report["source"]["kind"] == "store" and report["summary"]["n_predicted"] == len(
        toy_store
    )
    ids = np.arange(len(toy_store))
    direct = ComplianceEstimator.from_checkpoint(runs["top10nn_all"]).predict(
        toy_store.frames[ids], **_store_inputs(toy_store, ids)
    )
    got = np.array([p["pred_pa"] for p in report["predictions"]])
    np.testing.assert_allclose(got, direct.modulus_pa, rtol=1e-5)
    assert {"log10_accuracy", "nmse"} <= set(report["summary"]["metrics"])
    assert "log10 accuracy" in format_predictions(report)


def test_predict_path_on_a_raw_grasp_dir_equals_the_imported_store(runs, toy_store, tmp_path):
    tree = tmp_path / "tree"
    write_tree(tree, grasps=1, augmentations=2, size=(48, 64))
    checkpoint = runs["top10nn_all"]
    # The checkpoint's training store is 32x32: raw frames take the importer's resize to
    # it, so the comparison store is imported at that size.
    import_burgess(tree, tmp_path / "imported", image_size=toy_store.image_size, progress=False)
    from_store = predict_path(checkpoint, tmp_path / "imported")
    by_source = {p["source_path"]: p["pred_pa"] for p in from_store["predictions"]}

    grasp_dir = tree / "rubber_ball" / "grasp=0"
    report = predict_path(checkpoint, grasp_dir)
    assert report["source"]["kind"] == "grasp_dir"
    assert len(report["predictions"]) == 4  # 2 augmentations x 2 fingers
    for p in report["predictions"]:
        relative = str(p["source_path"]).split("tree/", 1)[1]
        assert p["pred_pa"] == pytest.approx(by_source[relative], rel=1e-5)
        assert p["true_pa"] == pytest.approx(8.0e5)
    one = predict_path(checkpoint, grasp_dir / "augmentation=1", fingers="markers")
    assert len(one["predictions"]) == 1 and one["predictions"][0]["finger"] == "markers"


def test_predict_path_skips_a_corrupt_augmentation_like_the_importer(runs, tmp_path):
    tree = tmp_path / "tree"
    write_tree(tree, grasps=1, augmentations=2, size=(48, 64))
    grasp_dir = tree / "rubber_ball" / "grasp=0"
    (grasp_dir / "augmentation=1" / "RGB.pkl").write_bytes(b"not a pickle")
    report = predict_path(runs["top10nn_all"], grasp_dir)
    assert len(report["predictions"]) == 2  # augmentation 0, both fingers
    assert {p["augmentation"] for p in report["predictions"]} == {0}
    (bad,) = report["skipped"]
    assert bad["augmentation"] == 1 and bad["source_path"].endswith("augmentation=1")
    assert "RGB.pkl" in bad["reason"]
    assert report["summary"]["n_skipped"] == 1
    with pytest.raises(ValueError, match=r"RGB\.pkl"):  # the only sample asked for is bad
        predict_path(runs["top10nn_all"], grasp_dir / "augmentation=1")


def test_predict_path_skips_samples_missing_an_input(runs, toy_store, tmp_path):
    store_copy = tmp_path / "store"
    shutil.copytree(toy_store.path, store_copy)
    samples = pd.read_parquet(store_copy / "samples.parquet")
    samples.loc[[1, 5], "hertz_estimate_pa"] = np.nan
    samples.to_parquet(store_copy / "samples.parquet", index=False)
    report = predict_path(runs["top10nn_all"], store_copy)
    assert [s["sample_id"] for s in report["skipped"]] == [1, 5]
    assert "missing estimates" in report["skipped"][0]["reason"]
    assert report["summary"]["n_predicted"] == len(samples) - 2
    assert "(missing estimates (NaN): 2; see --json)" in format_predictions(report)
    # No sample has its estimates (a recording where they could not be computed): one
    # line naming the cause and the checkpoints that can, exit 2 (was: exit 0 and only
    # "Skipped N samples").
    samples["hertz_estimate_pa"] = np.nan
    samples.to_parquet(store_copy / "samples.parquet", index=False)
    result = CliRunner().invoke(app, ["predict", str(runs["top10nn_all"]), str(store_copy)])
    assert result.exit_code == 2, result.output
    lines = result.output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), result.output
    assert f"none of its {len(samples)} samples can be predicted" in lines[0]
    assert f"missing estimates (NaN): {len(samples)}" in lines[0]
    assert "a checkpoint of Image or ImageF or ImageFW or FW or DepthFW inputs can" in lines[0]


def _write_video(path, size=(40, 48)):
    height, width = size
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30, (width, height))
    for level in (40, 90, 160, 120):
        writer.write(np.full((height, width, 3), level, np.uint8))
    writer.release()


def test_predict_path_on_a_video_needs_an_image_checkpoint(runs, tmp_path):
    video = tmp_path / "BASIC_34_1.avi"
    _write_video(video)
    report = predict_path(runs["res_tf_image_s0"], video)
    assert report["source"]["kind"] == "video" and len(report["predictions"]) == 1
    with pytest.raises(ValueError, match="video carries no force"):
        predict_path(runs["top10nn_all"], video)


def test_predict_path_rejects_unknown_sources(runs, tmp_path):
    with pytest.raises(ValueError, match="no such file"):
        predict_path(runs["top10nn_all"], tmp_path / "missing")
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(ValueError, match="not a store, grasp directory or video"):
        predict_path(runs["top10nn_all"], tmp_path / "notes.txt")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="no grasp data found"):
        predict_path(runs["top10nn_all"], tmp_path / "empty")


# ---------------------------------------------------------------------- ensembles on runs
def test_ensemble_of_runs_and_its_calibration(runs, toy_store, tmp_path):
    dirs = [runs["res_tf_image_s0"], runs["res_tf_image_s1"]]
    ensemble = EnsembleEstimator.from_checkpoints(dirs)
    frames = toy_store.frames[:5]
    result = ensemble.predict(frames)
    members = [ComplianceEstimator.from_checkpoint(d).predict(frames) for d in dirs]
    stacked = np.stack([m.log10_modulus_pa for m in members])
    np.testing.assert_allclose(result.log10_modulus_pa, stacked.mean(axis=0), atol=1e-9)
    assert np.all(result.interval_log10[0] <= result.log10_modulus_pa)

    report = ensemble_calibration(dirs, level=0.8)
    split = Split.load(dirs[0] / "split.json")
    assert report["n_test"] == len(split.test_ids) and report["n_members"] == 2
    assert report["coverage_val_calibrated"] >= 0.8  # the fitted scale does what it says
    assert 0.0 <= report["coverage_raw"] <= 1.0 and report["scale"] > 0

    # Members trained on another split cannot be calibrated together.
    other = tmp_path / "other_run"
    shutil.copytree(dirs[1], other)
    moved = Split.load(other / "split.json")
    replace(moved, val_ids=moved.test_ids, test_ids=moved.val_ids).save(other / "split.json")
    with pytest.raises(ValueError, match="another split"):
        ensemble_calibration([dirs[0], other])


def test_predictions_type_is_exported():
    assert Prediction.from_normalised(
        np.array([0.5]), NormalisationConstants(), True
    ).modulus_pa == pytest.approx(10**7.5)


# ---------------------------------------------------------------------- command line
def _cli_commands() -> set[str]:
    from tactile_compliance.cli import app

    return {c.name or c.callback.__name__ for c in app.registered_commands}


@pytest.mark.skipif(
    not {"predict", "export"} <= _cli_commands(),
    reason="`predict` / `export` are not wired into the CLI yet",
)
def test_cli_predict_and_export(runs, toy_store, tmp_path):
    from typer.testing import CliRunner

    from tactile_compliance.cli import app

    runner = CliRunner()
    checkpoint = str(runs["top10nn_all"])
    result = runner.invoke(app, ["predict", checkpoint, str(toy_store.path), "--json"])
    assert result.exit_code == 0, result.output
    assert len(json.loads(result.stdout)["predictions"]) == len(toy_store)
    result = runner.invoke(app, ["predict", checkpoint, str(toy_store.path)])
    assert result.exit_code == 0 and "Estimate" in result.stdout
    result = runner.invoke(app, ["predict", checkpoint, str(tmp_path / "missing")])
    assert result.exit_code != 0 and "no such file" in result.output
    result = runner.invoke(app, ["export", checkpoint, "--onnx", str(tmp_path / "m.onnx")])
    assert result.exit_code == 0, result.output
    assert "Parity" in result.stdout and (tmp_path / "m.onnx").is_file()
