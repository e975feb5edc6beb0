"""SMAC3 tuning: the paper's search spaces, a handful of trials on a tiny store, resuming."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any, ClassVar

import pandas as pd
import pytest
import yaml

pytest.importorskip("smac")

from torch import nn
from typer.testing import CliRunner

from epoch_trace import (
    committed_epochs,
    default_sigint,
    read_trace,
    traced_env,
    wait_until_midway,
)
from tactile_compliance.cli import app
from tactile_compliance.config import config_to_dict, load_config
from tactile_compliance.models import (
    InputStrategy,
    SearchDimension,
    TactileModel,
    create_backbone,
    create_model,
    list_models,
    register_model,
)
from tactile_compliance.models import registry as registry_module
from tactile_compliance.training import hpo
from tactile_compliance.training.experiment_file import expand_experiment, load_experiment
from tactile_compliance.training.hpo.drivers import balance_budget
from tactile_compliance.training.hpo.objectives import last_epoch_val_nmse, trial_cost
from toy_store import make_toy_store

TOP10 = ["data.image_size=[72,72]", "augmentation.enabled=false"]
REAL_TRAIN_TRIAL = hpo.objectives._train_trial


@pytest.fixture(scope="module")
def toy_store(tmp_path_factory):
    return make_toy_store(tmp_path_factory.mktemp("toy") / "store")


# ---------------------------------------------------------------------------- spaces
@pytest.mark.parametrize("model", ["top10nn", "vgg_lstm", "res_tf"])
@pytest.mark.parametrize("inputs", ["Image", "ImageF", "ImageFW", "ALL"])
def test_search_space_matches_the_paper_and_builds_models(model, inputs):
    space = hpo.search_space(model, inputs, seed=1)
    names = set(space.keys())
    choices = {name: list(space[name].choices) for name in names}
    assert len(choices["training.lr"]) == 45 and 1e-2 in choices["training.lr"]
    assert 9e-6 in choices["training.lr"] and 1e-6 in choices["training.lr"]
    assert choices["training.gamma"][0] == "none" and len(choices["training.gamma"]) == 11
    assert choices["training.batch_size"] == [8, 16, 32, 64, 128]
    hparams = {n.removeprefix("model.hparams.") for n in names if n.startswith("model.")}
    # Towers of disabled inputs are not searched.
    assert ("estimation_sizes" in hparams or "elastic_dim" in hparams) == (inputs == "ALL")
    assert ("fwe_size" in hparams or "force_dim" in hparams) == (inputs != "Image")
    if model == "res_tf":
        assert choices["model.hparams.num_heads"] == [1, 2, 4, 8, 16]
        assert choices["model.hparams.num_layers"] == [2, 3, 4, 5, 6]
    # Every sampled configuration is a valid config, and (but VGG16, too big to build
    # 16 times in a test) a model that builds.
    for config in [space.get_default_configuration(), *space.sample_configuration(4)]:
        cfg = load_config(
            "default", [f"model.name={model}", f"inputs={inputs}", *hpo.trial_overrides(config)]
        )
        if model != "vgg_lstm":
            create_model(model, inputs=inputs, **cfg.model.hparams)


def test_search_space_defaults_are_the_paper_settings():
    def defaults(model, inputs):
        space = hpo.search_space(model, inputs)
        return hpo.trial_values(space.get_default_configuration())

    vgg = defaults("vgg_lstm", "ALL")
    # lr and batch size are on the grid; gamma 0.97974 is not: the nearest choice.
    assert vgg["training.lr"] == 3e-4 and vgg["training.batch_size"] == 16
    assert vgg["training.gamma"] == 0.98 and vgg["model.hparams.hidden_size"] == 256
    res_image = defaults("res_tf", "Image")
    assert res_image["training.lr"] == 8e-5 and res_image["model.hparams.num_layers"] == 5
    assert res_image["model.hparams.decoder_sizes"] == [256, 256, 128]  # nearest to [256]
    res_all = defaults("res_tf", "ALL")
    assert res_all["training.lr"] == 1e-4 and res_all["training.batch_size"] == 32
    assert res_all["model.hparams.num_layers"] == 4
    top = defaults("top10nn", "ImageF")
    assert top["training.lr"] == 3e-6 and top["training.gamma"] is None


class _TinyTunable(TactileModel):
    """A throwaway model that declares its own search space."""

    default_training: ClassVar[dict[str, Any]] = {"lr": 2e-3, "batch_size": 8, "gamma": None}
    hpo_space = (
        *TactileModel.hpo_space,
        SearchDimension.hparam("channels", (2, 4, 8)),
        SearchDimension.hparam("force_dim", (4, 8), needs=("force",)),
        SearchDimension.hparam("sizes", ((8,), (16, 8)), needs=("force", "width")),
    )

    def __init__(
        self,
        inputs: InputStrategy | str = "ALL",
        channels: int = 4,
        force_dim: int = 8,
        sizes: tuple[int, ...] = (16, 8),
    ) -> None:
        super().__init__(inputs, {"channels": channels, "force_dim": force_dim, "sizes": sizes})
        self.backbone = create_backbone("resnet18")
        self.out = nn.Linear(3 * self.backbone.feature_dim, 1)

    def _head(self, features, scalars):
        return self.out(features.flatten(1)).squeeze(1)


def test_any_registered_model_is_tunable_with_its_declared_space():
    try:
        register_model("tiny_tunable_model")(_TinyTunable)
        image = hpo.search_space("tiny_tunable_model", "Image", seed=0)
        assert set(image.keys()) == {
            "training.lr",
            "training.gamma",
            "training.batch_size",
            "model.hparams.channels",
        }
        space = hpo.search_space("tiny_tunable_model", "ImageF", seed=0)
        assert {"model.hparams.force_dim", "model.hparams.sizes"} <= set(space.keys())
        default = hpo.trial_values(space.get_default_configuration())
        # Defaults: the class's paper settings, else its constructor defaults.
        assert default["training.lr"] == 2e-3 and default["training.batch_size"] == 8
        assert default["model.hparams.channels"] == 4 and default["model.hparams.sizes"] == [16, 8]
        for config in [space.get_default_configuration(), *space.sample_configuration(3)]:
            cfg = load_config(
                "default",
                [
                    "model.name=tiny_tunable_model",
                    "inputs=ImageF",
                    *hpo.trial_overrides(config),
                ],
            )
            model = create_model("tiny_tunable_model", "ImageF", **cfg.model.hparams)
            assert model.hparams["channels"] in (2, 4, 8)
    finally:
        registry_module._REGISTRY.pop("tiny_tunable_model", None)
    assert "tiny_tunable_model" not in list_models()
    with pytest.raises(hpo.ConfigError, match="tunable"):
        hpo.search_space("tiny_tunable_model")


# ---------------------------------------------------------------------------- objective
# A validation curve whose best epoch (1) is not its last (3).
CURVE = [0.30, 0.05, 0.20, 0.25]


def _fake_run(run_dir: Path, val_nmse: list[float]) -> dict[str, Any]:
    """A run directory whose epoch log holds ``val_nmse`` per epoch (train and validation
    values on separate lines, as Lightning logs them), and its ``train`` result."""
    log = run_dir / "logs" / "metrics.csv"
    log.parent.mkdir(parents=True)
    lines = ["epoch,step,train_loss,val_nmse"]
    for epoch, value in enumerate(val_nmse):
        lines += [f"{epoch},{2 * epoch},0.5,", f"{epoch},{2 * epoch + 1},,{value}"]
    log.write_text("\n".join(lines) + "\n")
    best = min(range(len(val_nmse)), key=val_nmse.__getitem__)
    return {"run_dir": str(run_dir), "best_val_nmse": val_nmse[best], "best_epoch": best}


def test_trial_cost_reads_the_last_or_the_best_epoch(tmp_path):
    result = _fake_run(tmp_path / "run", CURVE)
    assert last_epoch_val_nmse(tmp_path / "run") == CURVE[-1]
    assert trial_cost(result, "last") == CURVE[-1]
    assert trial_cost(result, "best") == min(CURVE)
    # A result that records the last epoch itself is read directly.
    assert trial_cost({**result, "last_val_nmse": 0.125}, "last") == 0.125
    with pytest.raises(hpo.ConfigError, match="objective must be one of last, best"):
        trial_cost(result, "final")
    (tmp_path / "empty" / "logs").mkdir(parents=True)
    (tmp_path / "empty" / "logs" / "metrics.csv").write_text("epoch,step,train_loss\n0,0,0.5\n")
    with pytest.raises(ValueError, match="no epoch with a validation N-MSE"):
        last_epoch_val_nmse(tmp_path / "empty")
    with pytest.raises(ValueError, match="cannot read the epoch log"):
        last_epoch_val_nmse(tmp_path / "nowhere")


def _fake_trials(monkeypatch, curves: dict[str, list[float]]) -> list[Any]:
    """Replace training by fake runs with ``curves[model]``; returns the configs trained."""
    trained: list[Any] = []

    def fake(cfg, trials_dir):
        trained.append(cfg)
        run_dir = Path(trials_dir) / f"{cfg.model.name}-{len(trained)}"
        return _fake_run(run_dir, curves[cfg.model.name][: cfg.training.max_epochs])

    monkeypatch.setattr(hpo.objectives, "_train_trial", fake)
    return trained


def test_trial_objective_scores_the_last_epoch_of_the_whole_budget(tmp_path, monkeypatch):
    base = config_to_dict(load_config("default", ["model.name=top10nn", "inputs=Image"]))
    config = hpo.search_space("top10nn", "Image", seed=0).get_default_configuration()
    trained = _fake_trials(monkeypatch, {"top10nn": CURVE})
    last = hpo.TrialObjective(base, str(tmp_path / "last"))  # the default: the paper's
    assert last(config, budget=4) == CURVE[-1]
    # No early stopping: the published trials train their whole budget.
    assert trained[-1].training.patience == 0 and trained[-1].training.max_epochs == 4
    best = hpo.TrialObjective(base, str(tmp_path / "best"), objective="best")
    assert best(config, budget=4) == min(CURVE)
    assert trained[-1].training.patience == 30  # the base config's early stopping
    assert last(config, budget=2) == CURVE[1]  # the last of 2 epochs


def test_balance_objective_averages_the_models_last_epochs(tmp_path, monkeypatch):
    bases = [
        config_to_dict(load_config("default", [f"model.name={m}", "inputs=Image"]))
        for m in ("top10nn", "res_tf")
    ]
    curves = {"top10nn": CURVE, "res_tf": [0.2, 0.1, 0.1, 0.4]}
    trained = _fake_trials(monkeypatch, curves)
    last = hpo.BalanceObjective(bases, str(tmp_path / "last"), epochs=4)
    assert last({"t_balance_percent": 37}) == pytest.approx((CURVE[-1] + 0.4) / 2)
    assert {(c.sampling.strategy, c.sampling.t_balance) for c in trained} == {("balanced", 0.37)}
    assert {(c.training.max_epochs, c.training.patience) for c in trained} == {(4, 0)}
    best = hpo.BalanceObjective(bases, str(tmp_path / "best"), epochs=4, objective="best")
    assert best({"t_balance_percent": 37}) == pytest.approx((min(CURVE) + 0.1) / 2)


def test_balance_budget_defaults_and_the_paper_switch():
    assert balance_budget() == (10, 30)
    assert balance_budget(paper_budget=True) == (50, 132)  # the paper's t_balance search
    assert balance_budget(20, None, paper_budget=True) == (20, 132)  # explicit values win
    assert balance_budget(None, 5) == (10, 5)
    with pytest.raises(hpo.ConfigError, match=">= 1"):
        balance_budget(0)


def test_unknown_objective_fails_before_anything_runs(tmp_path):
    for search in (hpo.tune, hpo.tune_balance):
        args = ("top10nn",) if search is hpo.tune else ()
        with pytest.raises(hpo.ConfigError, match="objective must be one of last, best"):
            search(*args, objective="final", store=tmp_path, output_dir=tmp_path / "t")
    assert not (tmp_path / "t").exists()


# ---------------------------------------------------------------------------- tune
def _count_trainings(monkeypatch, fail_after: int | None = None) -> list[str]:
    """Record every trial that trains; raise KeyboardInterrupt after ``fail_after`` trials."""
    trained: list[str] = []

    def counting(cfg, trials_dir):
        run_dir = Path(trials_dir) / hpo.config_hash(cfg)
        if fail_after is not None and len(trained) >= fail_after:
            raise KeyboardInterrupt  # as if the user pressed Ctrl-C during this trial
        if not (run_dir / "metrics.json").exists():
            trained.append(run_dir.name)
        return REAL_TRAIN_TRIAL(cfg, trials_dir)

    monkeypatch.setattr(hpo.objectives, "_train_trial", counting)
    return trained


def test_tune_runs_a_few_trials_and_resumes(toy_store, tmp_path, monkeypatch):
    out = tmp_path / "tune"
    kwargs = dict(
        store=toy_store.path,
        overrides=TOP10,
        min_epochs=1,
        max_epochs=3,
        output_dir=out,
        progress=False,
    )
    # The same search as the command line writes it.
    command = ["tune", "top10nn", "--inputs", "Image", "--store", str(toy_store.path)]
    command += ["--out", str(out), "--min-epochs", "1", "--max-epochs", "3"]
    command += [f"--set={override}" for override in TOP10]
    # 1. The command, interrupted after 2 trials (Ctrl-C): exit 130 and how to go on.
    trained = _count_trainings(monkeypatch, fail_after=2)
    interrupted = CliRunner().invoke(app, [*command, "--trials", "4"])
    assert interrupted.exit_code == 130, interrupted.output
    assert "interrupted; re-run the same command to continue" in interrupted.output
    assert len(trained) == 2
    # 2. Resumed: SMAC's run history is reloaded, finished trials are not trained again.
    trained = _count_trainings(monkeypatch)
    result = hpo.tune("top10nn", "Image", trials=4, **kwargs)
    table = pd.read_csv(result.trials_path)
    assert len(table) == 4 and result.trials == 4
    assert not table.duplicated(["config_id", "budget"]).any()
    assert set(table["status"]) == {"SUCCESS"} and set(table["budget"]) <= {1.0, 3.0}
    assert len(trained) == 2  # only the two trials that had not run
    at_best_budget = table[table["budget"] == result.best_budget]
    assert result.best_cost == pytest.approx(at_best_budget["cost"].min())
    # 3. The same command again is a no-op; more trials extend the same search.
    trained = _count_trainings(monkeypatch)
    assert hpo.tune("top10nn", "Image", trials=4, **kwargs).best == result.best
    assert trained == []
    extended = hpo.tune("top10nn", "Image", trials=6, **kwargs)
    assert extended.trials == 6 and len(trained) == 2
    assert len(list((out / "smac").iterdir())) == 1  # one search, continued
    # The command with --json: the same search (nothing trained), its result on stdout.
    trained = _count_trainings(monkeypatch)
    printed = CliRunner().invoke(app, [*command, "--trials", "6", "--json"])
    assert printed.exit_code == 0, printed.output
    assert trained == []
    document, expected = json.loads(printed.stdout), extended.to_dict()
    assert document.pop("wall_time_s") >= 0 and expected.pop("wall_time_s") >= 0
    assert document == expected and document["best"] == extended.best
    # 4. What it wrote is accepted by train/experiment directly.
    best = load_config(extended.config_path)
    assert best.model.name == "top10nn" and best.inputs == "Image"
    assert best.training.max_epochs == 200  # the base config's epochs, not the budget
    resolved = config_to_dict(best)
    for key, value in extended.best.items():
        node = resolved
        for part in key.split("."):
            node = node[part]
        assert node == value, key
    cells = expand_experiment(load_experiment(extended.config_path), seeds=3)
    assert len(cells) == 3 and {c.cfg.training.lr for c in cells} == {best.training.lr}
    # tuned.yaml plugs the tuned values into one model of a grid.
    (tmp_path / "grid.yaml").write_text(
        "description: uses tuned values\n"
        "grid: {model.name: [top10nn, res_tf]}\n"
        f"rules:\n  - when: {{model.name: top10nn}}\n    include: {extended.tuned_path}\n"
    )
    by_model = {
        c.cfg.model.name: c.cfg for c in expand_experiment(load_experiment(tmp_path / "grid.yaml"))
    }
    assert by_model["top10nn"].training.lr == best.training.lr
    assert by_model["top10nn"].model.hparams == best.model.hparams
    assert by_model["res_tf"].model.hparams == {}
    # Trials keep their results but not their weights.
    trial_dirs = list((out / "trials").iterdir())
    assert len(trial_dirs) == 6
    assert all((d / "metrics.json").exists() and not (d / "best.pt").exists() for d in trial_dirs)
    # Scored as published: the last epoch of a trial that trained its whole budget.
    assert {load_config(d / "config.yaml").training.patience for d in trial_dirs} == {0}
    costs = sorted(pd.read_csv(extended.trials_path)["cost"])
    assert costs == pytest.approx(sorted(last_epoch_val_nmse(d) for d in trial_dirs))


def test_tune_balance_writes_an_experiment_with_the_tuned_value(toy_store, tmp_path):
    grid = tmp_path / "grid.yaml"
    grid.write_text(
        "description: balanced toy grid\n"
        "set: {sampling.strategy: balanced, augmentation.enabled: false,"
        " training.lr: 1.0e-3, training.batch_size: 16}\n"
        "grid: {model.name: [top10nn, res_tf], inputs: [Image]}\n"
        "seeds: 2\n"
        "rules:\n"
        "  - when: {model.name: top10nn}\n"
        "    set: {data.image_size: [72, 72]}\n"
        "  - when: {model.name: res_tf}\n"
        "    set: {data.image_size: [32, 32], model.freeze_backbone: true,\n"
        "          model.hparams: {num_layers: 1, embedding_dim: 32, output_dim: 32}}\n"
    )
    result = hpo.tune_balance(
        grid,
        models=["top10nn", "res_tf"],
        inputs="Image",
        epochs=1,
        trials=2,
        store=toy_store.path,
        output_dir=tmp_path / "bal",
        progress=False,
    )
    t = result.best["sampling.t_balance"]
    assert 0.0 <= t <= 1.0 and result.trials == 2
    trials = pd.read_csv(result.trials_path)
    assert trials["cost"].min() == pytest.approx(result.best_cost)
    # Each trial trained both models for one epoch, balanced at its t_balance.
    configs = [
        json.loads((d / "metrics.json").read_text())
        for d in (tmp_path / "bal" / "trials").iterdir()
    ]
    assert {c["model"] for c in configs} == {"top10nn", "res_tf"}
    assert {c["sampling"] for c in configs} == {"balanced"} and len(configs) == 4
    assert {c["epochs_trained"] for c in configs} == {1}
    # The experiment file it wrote runs the whole grid with the tuned value.
    cells = expand_experiment(load_experiment(result.config_path), store=toy_store.path)
    assert len(cells) == 4
    assert {(c.cfg.sampling.strategy, c.cfg.sampling.t_balance) for c in cells} == {("balanced", t)}
    for path in result.extra_paths:
        assert load_config(path).sampling.t_balance == t


# ------------------------------------------------------------ the command interrupted
#: Two trials of two epochs each (with min = max epochs Hyperband has one budget), so a
#: trial can be caught midway after the first one finished.
KILL_TRIALS, KILL_EPOCHS = 2, 2


def _tune_command(store, out: Path, trace: Path) -> subprocess.Popen:
    """``tactile-compliance tune`` as a user runs it (serial trials in its own process),
    every training epoch traced."""
    command = [sys.executable, "-m", "tactile_compliance.cli", "tune", "top10nn"]
    command += ["--inputs", "Image", "--store", str(store.path), "--out", str(out)]
    command += [f"--set={override}" for override in TOP10]
    command += ["--trials", str(KILL_TRIALS), "--min-epochs", str(KILL_EPOCHS)]
    command += ["--max-epochs", str(KILL_EPOCHS)]
    return subprocess.Popen(
        command,
        env=traced_env(trace.parent / "site", trace),
        preexec_fn=default_sigint,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )


def _history(out: Path) -> pd.DataFrame:
    """trials.csv without the measured time: config id, budget, cost, status, values."""
    return pd.read_csv(out / "trials.csv").drop(columns="time_s")


@pytest.fixture(scope="module")
def small_store(tmp_path_factory):
    # Frames at the training size (no resizing), two or three batches per epoch.
    return make_toy_store(
        tmp_path_factory.mktemp("small") / "store", n_objects=8, grasps=2, size=(72, 72)
    )


@pytest.fixture(scope="module")
def uninterrupted_tune(small_store, tmp_path_factory) -> Path:
    """The reference: the same search run once without interruption (its output dir)."""
    root = tmp_path_factory.mktemp("uninterrupted-tune")
    reference = _tune_command(small_store, root / "tune", root / "trace")
    _, err = reference.communicate(timeout=600)
    assert reference.returncode == 0, err[-3000:]
    return root / "tune"


@pytest.mark.slow  # 84 s at load 6-8 with its reference search; cheaper tests: docs/testing.md
@pytest.mark.parametrize("signum", [signal.SIGKILL, signal.SIGINT], ids=["SIGKILL", "SIGINT"])
def test_interrupted_tune_resumes_without_training_a_finished_trial_again(
    small_store, uninterrupted_tune, tmp_path, signum
):
    """SIGKILL or SIGINT `tune` with one trial finished and the next one midway; the same
    command again never trains a finished trial or a committed epoch again, and keeps the
    trials before the interruption exactly. SMAC does not save its random state, so what
    it proposes afterwards may differ from the uninterrupted search (docs/testing.md)."""
    reference_out = uninterrupted_tune
    out, trace = tmp_path / "tune", tmp_path / "trace"
    proc = _tune_command(small_store, out, trace)
    try:
        midway = wait_until_midway(
            proc,
            trace,
            lambda: out.exists() and any((out / "trials").glob("*/metrics.json")),
            timeout_s=300,
            what="tune",
        )
    finally:
        proc.send_signal(signum)
        _, err = proc.communicate(timeout=120)
    # Ctrl-C: "interrupted: re-run to continue" (130).
    assert proc.returncode == (130 if signum == signal.SIGINT else -signal.SIGKILL), err[-3000:]
    finished = {d.parent for d in (out / "trials").glob("*/metrics.json")}
    assert finished and midway not in finished
    committed = {d: committed_epochs(d) for d in (out / "trials").iterdir() if d not in finished}
    assert committed[midway] >= 1  # 1, unless epoch 1 ended in the instant before the kill
    first_pids = {pid for pid, _, _ in read_trace(trace)}

    rerun = _tune_command(small_store, out, trace)
    _, err = rerun.communicate(timeout=600)
    assert rerun.returncode == 0, err[-3000:]

    # (a) No finished trial and no committed epoch is trained again.
    again: dict[Path, list[int]] = {}
    for pid, epoch, run_dir in read_trace(trace):
        if pid not in first_pids:
            again.setdefault(run_dir, []).append(epoch)
    assert not finished & set(again), again
    for run_dir, epochs in again.items():
        assert epochs == list(range(committed.get(run_dir, 0), KILL_EPOCHS)), again
    # (b) The history: every trial once, scored from its own run directory; the trials
    # finished before the kill exactly as the uninterrupted search ran them (SMAC's
    # proposals up to the kill are deterministic), every configuration both searches
    # tried at the same cost (trials are deterministic).
    history, uninterrupted = _history(out), _history(reference_out)
    assert len(history) == KILL_TRIALS and set(history["status"]) == {"SUCCESS"}
    assert not history.duplicated(["config_id", "budget"]).any()
    trial_dirs = [d for d in (out / "trials").iterdir() if (d / "metrics.json").exists()]
    assert sorted(history["cost"]) == pytest.approx(
        sorted(last_epoch_val_nmse(d) for d in trial_dirs), abs=0
    )
    before = len(finished)
    pd.testing.assert_frame_equal(history.iloc[:before], uninterrupted.iloc[:before])
    values = [c for c in history.columns if c not in ("config_id", "cost", "status")]
    both = history.merge(uninterrupted, on=values, suffixes=("", "_reference"))
    assert len(both) >= before + (midway in again)  # the killed trial was proposed again
    assert (both["cost"] == both["cost_reference"]).all()
    # The incumbent it reports is the best of its own history.
    tuned = yaml.safe_load((out / "tuned.yaml").read_text())
    scalars = ["training.lr", "training.batch_size", "model.hparams.img_feature_size"]
    best_rows = history[history["cost"] == history["cost"].min()]
    assert [tuned[k] for k in scalars] in best_rows[scalars].values.tolist()


@pytest.mark.slow
def test_tune_parallel_trials_on_dask(toy_store, tmp_path):
    result = hpo.tune(
        "top10nn",
        "Image",
        store=toy_store.path,
        overrides=TOP10,
        trials=6,
        min_epochs=1,
        max_epochs=3,
        workers=2,
        output_dir=tmp_path / "t",
        progress=False,
    )
    table = pd.read_csv(result.trials_path)
    assert len(table) == 6 and set(table["status"]) == {"SUCCESS"}


def test_tune_fails_fast_without_a_store(tmp_path):
    with pytest.raises(hpo.ConfigError, match="store not found"):
        hpo.tune("top10nn", store=tmp_path / "nowhere", output_dir=tmp_path / "t", progress=False)
    with pytest.raises(hpo.ConfigError, match="tunable"):
        hpo.search_space("resnet")


# A search through run_smac with a cheap, deterministic objective (a hash of the
# configuration's values), printed as JSON: what SMAC proposes, trial by trial.
_SEARCH_SCRIPT = """
import hashlib, json, sys
import smac
from ConfigSpace import Categorical, ConfigurationSpace
from tactile_compliance.training.hpo.smac_run import run_smac

space = ConfigurationSpace(seed=0)
space.add([
    Categorical("lr", [1e-4, 2e-4, 5e-4, 1e-3, 2e-3, 5e-3]),
    Categorical("batch_size", [8, 16, 32, 64, 128]),
    Categorical("dropout", [0.0, 0.1, 0.2, 0.3, 0.4]),
])
scenario = smac.Scenario(space, name="s", output_directory=sys.argv[1], deterministic=True,
                         seed=0, n_trials=12, min_budget=1, max_budget=1)

def objective(config, seed=0, budget=1):
    values = repr(sorted((k, float(v)) for k, v in dict(config).items()))
    return int(hashlib.sha256(values.encode()).hexdigest()[:8], 16) % 1000 / 1000 + 0.01

facade, _ = run_smac(smac.MultiFidelityFacade, scenario, objective,
                     intensifier=smac.MultiFidelityFacade.get_intensifier(scenario, eta=3),
                     client=None, overwrite=True, progress=False, label="s", trials=12)
configs = [facade.runhistory.ids_config[k.config_id] for k in facade.runhistory]
print(json.dumps([{k: float(v) for k, v in dict(c).items()} for c in configs]))
"""


def test_the_search_does_not_depend_on_pythons_string_hashing(tmp_path):
    """SMAC's local search orders its start points by hash (a set of configurations): the
    proposals after the initial design changed with PYTHONHASHSEED, i.e. from one `tune`
    process to the next. The same seed and costs must give the same search."""
    import os

    searches = []
    for hash_seed in ("1", "2", "3"):
        env = {**os.environ, "PYTHONHASHSEED": hash_seed, "OMP_NUM_THREADS": "1"}
        done = subprocess.run(
            [sys.executable, "-c", _SEARCH_SCRIPT, str(tmp_path / hash_seed)],
            env=env,
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert done.returncode == 0, done.stderr[-3000:]
        searches.append(json.loads(done.stdout.strip().splitlines()[-1]))
    assert len(searches[0]) == 12
    assert searches[1] == searches[0] and searches[2] == searches[0]
