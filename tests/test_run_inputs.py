"""The run's input contract is resolved once (``runs.run_inputs.RunInputs``) and read by
every consumer (issue 26, item 1).

A model is trained at 32x32 px on a store of 48x64 px frames, then used on a grasp
recorded at 60x84 px: ``predict`` on the imported store, ``live`` on the recording's
video, the ONNX export through both, and the evaluation path all give the same modulus.
A consumer that worked the frame size out for itself (the store's size for a model
trained at another) would break the agreement; the test checks that such a mistake shows.
The estimator is the record's too: the checkpoint, the ONNX file and the streaming
estimator carry the one the training store names.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

pytest.importorskip("onnxruntime")

from helpers import REPLAY_SIZE, cli, make_replay_grasp
from tactile_compliance.acquisition.readings import Readings
from tactile_compliance.acquisition.sensors import open_source
from tactile_compliance.data.dataset import GraspDataset
from tactile_compliance.data.normalisation import denormalise_modulus
from tactile_compliance.data.store import GraspStore
from tactile_compliance.inference import ComplianceEstimator
from tactile_compliance.inference.export import export_onnx
from tactile_compliance.inference.live import live_estimates
from tactile_compliance.inference.onnx import OnnxEstimator
from tactile_compliance.inference.predict import predict_path
from tactile_compliance.inference.streaming import StreamingEstimator
from tactile_compliance.physics.estimators import DEFAULT_ESTIMATOR
from tactile_compliance.runs.checkpoint import load_checkpoint
from tactile_compliance.runs.forward import predict_dataset
from tactile_compliance.training.train import train
from toy_store import make_toy_store, tiny_run_config

TRAIN_STORE_SIZE = (48, 64)
MODEL_SIZE = (32, 32)


@pytest.fixture(scope="module")
def setup(tmp_path_factory):
    """A run trained at MODEL_SIZE on a TRAIN_STORE_SIZE store; a grasp recorded at REPLAY_SIZE,
    imported as a store; the run's ONNX export."""
    root = tmp_path_factory.mktemp("run_inputs")
    toy = make_toy_store(root / "toy", n_objects=8, grasps=2, size=TRAIN_STORE_SIZE)
    cfg = tiny_run_config(
        toy.path,
        root / "runs",
        "res_tf",
        [
            "model.hparams={num_layers: 1, embedding_dim: 64, output_dim: 64}",
            f"data.image_size=[{MODEL_SIZE[0]},{MODEL_SIZE[1]}]",
            "inputs=ImageFW",
            "training.max_epochs=1",
            "training.lr=1e-3",
        ],
    )
    run_dir = train(cfg, run_dir=root / "run", progress=False)["run_dir"]
    grasp = make_replay_grasp(root / "grasp", REPLAY_SIZE)
    data, store = root / "data", root / "store"
    cli(
        "record",
        f"video:{grasp['video']}",
        "--out",
        data,
        "--object",
        grasp["name"],
        "--modulus",
        grasp["modulus_pa"],
        "--readings",
        grasp["readings"],
    )
    cli("import", "burgess", data, "--out", store, "--fingers", "markerless")
    onnx_path = root / "model.onnx"
    export_onnx(run_dir, onnx_path)
    return {"run": run_dir, "grasp": grasp, "store": store, "onnx": onnx_path}


def test_the_record_is_resolved_once_and_carried_by_every_format(setup):
    record = load_checkpoint(f"{setup['run']}/best.pt").run_inputs
    assert record.image_size == MODEL_SIZE and record.store_image_size == TRAIN_STORE_SIZE
    assert record.inputs.value == "ImageFW" and record.channel_order == "RGB"
    assert record.estimator == DEFAULT_ESTIMATOR  # the toy store names none
    assert ComplianceEstimator.from_checkpoint(setup["run"]).run_inputs == record
    onnx_estimator = OnnxEstimator(setup["onnx"])
    assert onnx_estimator.run_inputs == record
    assert StreamingEstimator(onnx_estimator).analytical_estimator == DEFAULT_ESTIMATOR
    assert GraspStore.open(setup["store"]).image_size == REPLAY_SIZE  # a third size


def _live_final(members, grasp):
    readings = Readings.from_csv(grasp["readings"])
    with open_source(f"video:{grasp['video']}") as source:
        events = list(live_estimates(members, source, readings))
    assert events[-1]["final"]
    return events[-1]


def test_predict_live_onnx_and_evaluation_agree_across_frame_sizes(setup):
    # On the CPU, like ONNX Runtime here: a GPU's TF32 convolutions differ from it by
    # ~1e-4 decades, more than the round-off these comparisons allow (test_cuda.py).
    torch_estimator = ComplianceEstimator.from_checkpoint(setup["run"], device="cpu")
    onnx_estimator = OnnxEstimator(setup["onnx"])
    store = GraspStore.open(setup["store"])

    # predict on the 60x84 store with a model trained at 32x32 on 48x64 frames.
    report = predict_path(setup["run"], setup["store"], device="cpu")
    rows = {p["augmentation"]: p for p in report["predictions"]}
    assert len(rows) == len(store) and report["checkpoint"]["image_size"] == list(MODEL_SIZE)
    predicted = np.array([rows[a]["pred_log10_pa"] for a in sorted(rows)])
    assert np.isfinite(predicted).all()

    # The evaluation path (``evaluate``'s, after its sample filter) gives the same values.
    loaded = load_checkpoint(f"{setup['run']}/best.pt", device="cpu")
    ids = store.samples.sort_values("augmentation")["sample_id"].to_numpy()
    constants = loaded.run_inputs.constants
    evaluated = predict_dataset(
        loaded.model,
        GraspDataset(store, ids, constants, loaded.run_inputs.inputs),
        loaded.run_inputs,
    )
    evaluated_log10 = np.log10(denormalise_modulus(evaluated.astype(np.float64), constants))
    # 1e-4 decades, as for ONNX and live below: the two paths batch the samples
    # differently, and float32 sums then differ with the CPU's thread count (3.6e-5
    # decades on a 16-core Xeon; a wrong frame size moves the value by more, see below).
    np.testing.assert_allclose(evaluated_log10, predicted, rtol=0, atol=1e-4)

    # The ONNX export on the same store's samples.
    samples = store.samples.sort_values("augmentation")
    frames = store.load_frames(samples["sample_id"].to_numpy())
    scalars = {
        "force": samples[[f"force_n_{i}" for i in range(3)]].to_numpy(),
        "width": samples[[f"width_m_{i}" for i in range(3)]].to_numpy(),
    }
    onnx_values = onnx_estimator.predict(frames, **scalars).log10_modulus_pa
    np.testing.assert_allclose(onnx_values, predicted, rtol=0, atol=1e-4)

    # live on the recording itself (60x84 raw frames), with either runtime: the final
    # estimate is augmentation 0's.
    for member in (torch_estimator, onnx_estimator):
        final = _live_final([member], setup["grasp"])
        assert final["log10_modulus_pa"] == pytest.approx(rows[0]["pred_log10_pa"], abs=1e-4)


def test_a_consumer_that_re_derived_the_contract_would_disagree(setup):
    """The agreement above is no accident: the store's frame size instead of the model's
    gives other values."""
    estimator = ComplianceEstimator.from_checkpoint(setup["run"], device="cpu")
    report = predict_path(setup["run"], setup["store"], device="cpu")
    expected = next(p for p in report["predictions"] if p["augmentation"] == 0)["pred_log10_pa"]
    # Frames resized to the training store's size, as if None meant "the store's size".
    estimator.run_inputs = replace(estimator.run_inputs, image_size=TRAIN_STORE_SIZE)
    wrong_size = _live_final([estimator], setup["grasp"])["log10_modulus_pa"]
    assert abs(wrong_size - expected) > 1e-4


def test_predict_and_live_warn_once_when_the_source_differs_from_the_training_data(setup):
    """Issue 42: a model trained on 48x64 frames, run on a 60x84 source, says so once
    (``RunInputs.source_mismatch``), in ``predict``'s report and as one ``live`` warning."""
    report = predict_path(setup["run"], setup["store"], device="cpu")
    frames = [w for w in report["warnings"] if "trained on 48x64 px frames" in w]
    assert len(frames) == 1 and "gives 60x84 px" in frames[0], report["warnings"]
    readings = Readings.from_csv(setup["grasp"]["readings"])
    estimator = ComplianceEstimator.from_checkpoint(setup["run"], device="cpu")
    with open_source(f"video:{setup['grasp']['video']}") as source:
        events = list(live_estimates([estimator, estimator], source, readings))
    warned = [e["reason"] for e in events if e["event"] == "warning"]
    assert sum("trained on 48x64 px frames" in w for w in warned) == 1, warned
    assert len(warned) == len(set(warned))
    record = load_checkpoint(f"{setup['run']}/best.pt").run_inputs
    assert record.source_mismatch(TRAIN_STORE_SIZE, record.sensor, used="x") == []
