"""The training path end to end on a tiny learnable store (seconds per model)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import torch
from typer.testing import CliRunner

from tactile_compliance.cli import app
from tactile_compliance.data.normalisation import normalise_modulus
from tactile_compliance.data.splits import Split
from tactile_compliance.evaluation.evaluate import evaluate_run
from tactile_compliance.models import list_models
from tactile_compliance.runs.checkpoint import load_checkpoint
from tactile_compliance.training.train import train
from toy_store import make_toy_store, tiny_run_config

# Per model: settings that learn the toy task in a few CPU seconds. Top10NN trains its
# CNN end to end (it needs >= 65 px frames); the pretrained-backbone models use a frozen
# random backbone with cached features, as the CPU presets do.
FAST = {
    "top10nn": ["data.image_size=[72,72]", "training.lr=1e-3", "training.max_epochs=12"],
    "vgg_lstm": [
        "data.image_size=[32,32]",
        "model.freeze_backbone=true",
        "training.lr=1e-3",
        "training.max_epochs=25",
        "model.hparams={hidden_size: 64}",
    ],
    "res_tf": [
        "data.image_size=[32,32]",
        "model.freeze_backbone=true",
        "training.lr=3e-4",
        "training.max_epochs=25",
        "model.hparams={num_layers: 1, embedding_dim: 64, output_dim: 64}",
    ],
    # The frame-free model, on force and width (the toy store's width change encodes E).
    "scalar_mlp": ["inputs=FW", "training.lr=1e-2", "training.max_epochs=60"],
}


#: Upper bounds on the best validation N-MSE and the test N-MSE of each FAST run (seed 0,
#: float32), set at 2x the largest value MEASURED over seeds 0-4 on the toy store (the
#: test itself is seeded: same machine, same numbers). At seed 0 the median predictor
#: scores 0.044 (validation) and 0.063 (test): a model that learns nothing misses these
#: bounds by a factor of 6 or more.
#: Measured on 2026-11-25 (train() on these FAST configs with seed=0..4), best val / test:
#:   top10nn   val 1.02e-3 2.45e-3 2.19e-3 1.25e-3 1.32e-3  test 5.6e-4 3.0e-3 5.1e-3 1.4e-3 4.7e-3
#:   vgg_lstm  val 7.01e-5 2.19e-4 1.46e-4 3.33e-4 2.67e-4  test 2.9e-4 3.7e-4 9.4e-5 3.5e-4 1.1e-3
#:   res_tf    val 2.52e-4 5.87e-4 7.42e-4 7.67e-4 1.02e-3  test 4.2e-4 7.6e-4 6.2e-4 1.3e-3 2.9e-3
#: (seeds 0, 1, 2, 3, 4; the old bound, 0.6 x the median predictor, was 0.026 at seed 0.)
#: Measured on 2026-12-02, the same way:
#:   scalar_mlp val 3.44e-4 3.20e-4 4.85e-4 3.69e-4 4.48e-4  test 4.8e-4 7.6e-4 5.7e-4 8.1e-4 6.1e-4
NMSE_BOUND = {  # model: (best validation N-MSE, test N-MSE)
    "scalar_mlp": (1e-3, 1.7e-3),
    "top10nn": (5e-3, 1e-2),
    "vgg_lstm": (7e-4, 2.2e-3),
    "res_tf": (2.1e-3, 6e-3),
}
#: bf16-mixed against float32 on the same seed: the measured ratio best-val(bf16) /
#: best-val(fp32) was 0.85-1.08 for VGG-LSTM and 0.99-1.03 for Res-Tf over seeds 0-4;
#: bound 1.5x, a 50 % margin over the worst one (the old bound, 1.5 x fp32 + 0.002,
#: let VGG-LSTM's bf16 run be 30x worse than its float32 run).
BF16_RATIO_BOUND = 1.5


@pytest.fixture(scope="module")
def toy_store(tmp_path_factory):
    return make_toy_store(tmp_path_factory.mktemp("toy") / "store")


def _config(store, out, model, extra=()):
    return tiny_run_config(store.path, out, model, ["training.patience=100", *FAST[model], *extra])


@pytest.fixture(scope="module")
def fast_run(toy_store, tmp_path_factory):
    """``fast_run(model, precision)`` -> (config, result) of the FAST run, trained once per
    module (the float32 runs serve both the learning test and the bf16 comparison)."""
    done = {}

    def get(model, precision="32"):
        if (model, precision) not in done:
            out = tmp_path_factory.mktemp(f"{model}-{precision}")
            cfg = _config(toy_store, out, model, [f"training.precision={precision}"])
            done[model, precision] = (cfg, train(cfg, progress=False))
        return done[model, precision]

    return get


def _median_val_nmse(run_dir, store, constants) -> float:
    split = Split.load(run_dir / "split.json")
    moduli = store.samples["modulus_pa"].to_numpy()
    median = np.median(moduli[split.train_ids])
    y_val = normalise_modulus(moduli[split.val_ids], constants)
    return float(np.mean((y_val - normalise_modulus(median, constants)) ** 2))


def test_every_model_is_covered():
    assert sorted(FAST) == list_models() == sorted(NMSE_BOUND)


@pytest.mark.parametrize("model", sorted(FAST))
def test_tiny_run_learns_to_its_measured_accuracy(toy_store, fast_run, model):
    cfg, result = fast_run(model)
    run_dir = Path(result["run_dir"])
    val_bound, test_bound = NMSE_BOUND[model]
    assert result["best_val_nmse"] < val_bound, (result["best_val_nmse"], val_bound)
    assert result["test"]["nmse"] < test_bound, (result["test"]["nmse"], test_bound)
    # The bounds are far below what predicting the training median scores.
    median_val = _median_val_nmse(run_dir, toy_store, cfg.normalisation_constants())
    assert val_bound < 0.25 * median_val, (val_bound, median_val)
    assert test_bound < 0.25 * result["reference"]["median"]["nmse"]
    # The restored best weights reproduce the best epoch's validation score.
    assert result["val"]["nmse"] == pytest.approx(result["best_val_nmse"], rel=2e-3, abs=1e-5)
    for name in (
        "config.yaml",
        "split.json",
        "best.pt",
        "predictions.csv",
        "groups.csv",
        "logs/metrics.csv",
        "checkpoints/last.ckpt",
        "filter_report.json",
    ):
        assert (run_dir / name).exists(), name
    # Per-epoch training metrics: the loss is the MSE plus the (positive) l2 term.
    metrics = pd.read_csv(run_dir / "logs" / "metrics.csv")
    train_rows = metrics.dropna(subset=["train_loss"])
    assert len(train_rows) == metrics["epoch"].nunique() == result["epochs_trained"]
    assert (train_rows["train_loss"] > train_rows["train_mse"]).all()
    # The checkpoint describes itself.
    loaded = load_checkpoint(run_dir / "best.pt")
    assert loaded.meta["model_name"] == model and loaded.run_inputs.inputs.value == cfg.inputs
    assert loaded.meta["seed"] == cfg.seed and loaded.meta["backbone_weights"] == "none"
    assert loaded.meta["config"]["data"]["store"] == str(toy_store.path)
    # The run's image size: the configured one, none for the frame-free model.
    expected_size = tuple(cfg.data.image_size) if cfg.data.image_size else None
    assert loaded.run_inputs.image_size == expected_size
    assert loaded.run_inputs.store_image_size == toy_store.image_size
    # Re-running a finished configuration returns the stored result without training.
    assert train(cfg, progress=False) == result


@pytest.mark.parametrize(
    "model",
    [
        "vgg_lstm",
        # 83 s at load 18; the vgg_lstm case runs the same bf16-mixed path by default.
        pytest.param("res_tf", marks=pytest.mark.slow),
    ],
)
def test_bf16_mixed_head_learns_as_well_as_float32(fast_run, model):
    # bf16-mixed is the fast CPU path for heads on cached features (docs/training.md).
    half = fast_run(model, "bf16-mixed")[1]
    full = fast_run(model, "32")[1]
    assert half["best_val_nmse"] < NMSE_BOUND[model][0], half["best_val_nmse"]
    ratio = half["best_val_nmse"] / full["best_val_nmse"]
    assert ratio < BF16_RATIO_BOUND, (half["best_val_nmse"], full["best_val_nmse"])
    assert half["test"]["nmse"] < NMSE_BOUND[model][1], half["test"]["nmse"]


def test_evaluate_reproduces_the_test_metrics(toy_store, tmp_path):
    cfg = _config(toy_store, tmp_path, "top10nn", ["training.max_epochs=3"])
    result = train(cfg, progress=False)
    evaluation = evaluate_run(result["run_dir"])
    for key in ("log10_accuracy", "nmse", "r2"):
        assert evaluation.metrics[key] == pytest.approx(result["test"][key], abs=1e-5)
    stored = pd.read_csv(f"{result['run_dir']}/predictions.csv").query("split == 'test'")
    assert np.allclose(stored["pred_pa"].to_numpy(), evaluation.predictions["pred_pa"], rtol=1e-4)
    assert set(evaluation.groups["grouping"]) == {"all", "material", "shape", "soft_hard"}


def test_test_split_uses_the_best_epoch_not_the_last(toy_store, tmp_path):
    cfg = _config(toy_store, tmp_path, "top10nn", ["training.max_epochs=6", "training.lr=3e-2"])
    result = train(cfg, progress=False)
    log = pd.read_csv(f"{result['run_dir']}/logs/metrics.csv").dropna(subset=["val_nmse"])
    assert result["best_val_nmse"] == pytest.approx(log["val_nmse"].min(), rel=1e-5)
    assert result["best_epoch"] == int(log.loc[log["val_nmse"].idxmin(), "epoch"])
    meta = load_checkpoint(f"{result['run_dir']}/best.pt").meta
    assert meta["metrics"]["best_epoch"] == result["best_epoch"]


@pytest.mark.parametrize(
    "model",
    [
        # 40 s at load 18; a Top10NN run's resume runs by default in test_resume.py (the
        # SIGKILL kill test, and the resume line's test).
        pytest.param("top10nn", marks=pytest.mark.slow),
        "vgg_lstm",  # frozen + cached: last.ckpt holds the head only
    ],
)
def test_interrupted_run_resumes_from_its_checkpoint(toy_store, tmp_path, model):
    run_dir = tmp_path / "run"
    first = train(
        _config(toy_store, tmp_path, model, ["training.max_epochs=2"]),
        run_dir=run_dir,
        progress=False,
    )
    assert first["epochs_trained"] == 2
    if model == "vgg_lstm":
        last = run_dir / "checkpoints" / "last.ckpt"
        state = torch.load(last, map_location="cpu", weights_only=False)["state_dict"]
        # The frozen VGG16 is rebuilt on resume, so last.ckpt carries the head only.
        assert state and not any(k.startswith("model.backbone.") for k in state)
    (run_dir / "metrics.json").unlink()  # as if the process died after epoch 2
    resumed = train(
        _config(toy_store, tmp_path, model, ["training.max_epochs=4"]),
        run_dir=run_dir,
        progress=False,
    )
    assert resumed["epochs_trained"] == 4
    log = pd.read_csv(run_dir / "logs" / "metrics.csv").dropna(subset=["val_nmse"])
    # Epochs 0-1 from the first process, 2-3 from the resumed one: none repeated.
    assert sorted(log["epoch"].astype(int).tolist()) == [0, 1, 2, 3]
    # The model continued from epoch 2's weights: its best score can only improve on it.
    assert resumed["best_val_nmse"] <= first["best_val_nmse"]


def test_feature_cache_is_shared_across_seeds(toy_store, tmp_path):
    for seed in (0, 1):
        train(
            _config(toy_store, tmp_path, "res_tf", ["training.max_epochs=1", f"seed={seed}"]),
            progress=False,
        )
    caches = list((toy_store.path / "features").iterdir())
    assert len([c for c in caches if c.name.startswith("resnet")]) == 1
    meta = json.loads((caches[0] / "meta.json").read_text())
    assert meta["shape"][0] == len(toy_store)


def test_cli_train_and_evaluate(toy_store, tmp_path):
    runner = CliRunner()
    args = [
        "train",
        "--set",
        f"data.store={toy_store.path}",
        "--set",
        f"output_dir={tmp_path}",
        "--set",
        "data.image_size=[72,72]",
        "--set",
        "training.max_epochs=1",
        "--out",
        str(tmp_path / "cli-run"),
    ]
    result = runner.invoke(app, args)
    assert result.exit_code == 0, result.output
    assert "test log10 accuracy" in result.output
    result = runner.invoke(app, ["evaluate", str(tmp_path / "cli-run"), "--json"])
    assert result.exit_code == 0, result.output
    assert json.loads(result.output)["metrics"]["n"] > 0
    bad = runner.invoke(app, ["train", "--set", "training.lrr=1"])
    assert bad.exit_code == 2 and "lrr" in bad.output  # a bad config: exit 2 (cli/framework.py)


@pytest.mark.parametrize(
    "model_name, block", [("res_tf", "layer4"), ("vgg_lstm", "classifier"), ("top10nn", "fc")]
)
def test_finetune_last_block_trains_only_that_block(model_name, block):
    from tactile_compliance.data.normalisation import NormalisationConstants
    from tactile_compliance.models import create_model
    from tactile_compliance.runs.run_inputs import RunInputs
    from tactile_compliance.training.module import ComplianceModule

    model = create_model(model_name)
    module = ComplianceModule(
        model,
        RunInputs((224, 224), (224, 224), NormalisationConstants(), "ALL"),
        lr=1e-3,
        gamma=None,
        l2_weight=0.0,
        finetune="last_block",
    )
    trainable = {n for n, p in model.backbone.named_parameters() if p.requires_grad}
    assert trainable and all(n.startswith(f"{block}.") for n in trainable)
    assert {
        n for n, _ in model.backbone.named_parameters() if n.startswith(f"{block}.")
    } == trainable
    # The head always trains.
    head = [p for n, p in model.named_parameters() if not n.startswith("backbone.")]
    assert all(p.requires_grad for p in head)
    assert len(module.trainable_parameters()) == len(head) + len(trainable)


def test_tensorboard_without_package_is_a_clear_error(toy_store, tmp_path):
    pytest.importorskip("lightning")
    try:
        import tensorboard  # noqa: F401

        pytest.skip("tensorboard is installed")
    except ModuleNotFoundError:
        pass
    cfg = _config(
        toy_store, tmp_path, "top10nn", ["training.max_epochs=1", "training.tensorboard=true"]
    )
    with pytest.raises(ValueError, match="pip install tensorboard"):
        train(cfg, progress=False)


@pytest.mark.parametrize(
    "size, origin",
    [(None, "the store's frames are 32x32"), ("[48,64]", "data.image_size is 48x64")],
)
def test_frames_too_small_for_the_model_fail_before_the_run_directory(
    toy_store, tmp_path, size, origin
):
    """Top10NN's five unpadded convolutions need 65 px (its backbone class declares it):
    `train` says so in one line and leaves no run directory, not a half run from a
    failure in Lightning's first step."""
    from tactile_compliance.models import create_model

    minimum = create_model("top10nn").min_image_size
    assert minimum == 65
    out = tmp_path / "runs"
    args = ["train", "--set", f"data.store={toy_store.path}", "--set", f"output_dir={out}"]
    args += ["--set", "model.name=top10nn", "--set", "training.max_epochs=1"]
    if size is not None:
        args += ["--set", f"data.image_size={size}"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 2, result.output
    errors = [line for line in result.output.splitlines() if line.startswith("error:")]
    assert errors == [
        f"error: top10nn needs frames of at least {minimum}x{minimum} px, but {origin}: set "
        f"data.image_size to [{minimum}, {minimum}] or larger"
    ], result.output
    assert not out.exists() or not any(out.iterdir())


def test_a_saved_split_is_used_recorded_and_refused_for_another_store(toy_store, tmp_path):
    """``train --split FILE`` (issue 42): the run trains on the saved split (not one drawn
    with its seed), records the file, and a split of another store is one line."""
    from tactile_compliance.config import use_split_file
    from tactile_compliance.data.preprocess import filter_samples
    from tactile_compliance.data.splits import make_split_from_config, store_metadata

    cfg = _config(toy_store, tmp_path, "top10nn", ["training.max_epochs=1"])
    drawn_cfg = cfg.model_copy(update={"seed": 7})
    samples, _ = filter_samples(toy_store.samples, drawn_cfg)
    saved = make_split_from_config(samples, drawn_cfg, store_metadata(toy_store))
    saved.save(tmp_path / "split.json")
    assert saved != make_split_from_config(samples, cfg, store_metadata(toy_store))  # seed 0
    with_file = use_split_file(cfg, tmp_path / "split.json")
    assert with_file.split.seed == 7 and with_file.split.file == str(tmp_path / "split.json")
    result = train(with_file, progress=False)
    assert Split.load(Path(result["run_dir"]) / "split.json") == saved
    assert result["split_file"] == str(tmp_path / "split.json")
    assert "split.json" in (Path(result["run_dir"]) / "config.yaml").read_text()

    other = make_toy_store(tmp_path / "other", n_objects=6, grasps=2, seed=1)
    on_other = with_file.model_copy(
        update={"data": with_file.data.model_copy(update={"store": str(other.path)})}
    )
    with pytest.raises(ValueError, match="a split of another store") as refused:
        train(on_other, progress=False)
    assert len(str(refused.value).splitlines()) == 1 and "split " in str(refused.value)
