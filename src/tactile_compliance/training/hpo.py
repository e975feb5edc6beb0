"""Hyperparameter tuning with SMAC3: the paper's search spaces, epochs as the budget.

* :func:`tune` searches one model's hyperparameters for one input strategy with SMAC's
  multi-fidelity facade (Hyperband over epochs, ``min_epochs``..``max_epochs``), objective
  the best validation N-MSE of the run, 132 trials by default, deterministic, as in the
  paper. Every trial is one call of the training path
  (:func:`tactile_compliance.training.train.train`) with ``training.max_epochs`` set to the
  trial's budget.
* :func:`tune_balance` searches ``sampling.t_balance`` in [0, 1] (step 0.01) with cost =
  mean validation N-MSE of the models (default: all three) after a fixed number of epochs.

Both write what they found as files the other commands accept directly::

    OUT/best.yaml          full config: `train --config OUT/best.yaml`,
                           `experiment OUT/best.yaml --seeds 10`
    OUT/tuned.yaml         only the tuned keys (dotted); `include:` it in an experiment rule
    OUT/NAME-tuned.yaml    tune-balance from experiment NAME: that experiment with the tuned
                           t_balance (`experiment OUT/NAME-tuned.yaml [--quick]`)
    OUT/trials.csv         every trial: hyperparameters, budget, cost, status
    OUT/trials/HASH/       the trials' run directories (results kept, weights deleted)
    OUT/smac/NAME/SEED/    SMAC's own state: runhistory, intensifier, scenario

**Resuming.** Re-running the same command continues from SMAC's run history: finished
trials are not repeated, and a trial that was interrupted resumes from its checkpoint
(``train`` is idempotent). Raising ``--trials`` extends a finished search. The SMAC
directory name hashes everything that defines the search (base config, search space,
budgets, eta, seed, SMAC version), so a different search never mixes with an old one.

**Parallel trials** go through SMAC's Dask support (``workers > 1`` or ``scheduler``).
The frozen-backbone feature cache is computed once before the first trial.

Search spaces (``search_space``; categorical, as in the published code): lr in
{i * 10^-j : i = 1..9, j = 2..6}; gamma in {0.95, 0.955, ..., 0.995, none}; batch in
{8, 16, 32, 64, 128}; then per model (only for the inputs the strategy enables):

* Res-Tf: video and decoder dropout {0, .., 0.4}, layers {2..6}, heads {1, 2, 4, 8, 16},
  embedding and output dim {128, 256, 512, 1024}, decoder sizes (5 choices); with E:
  estimation decoder sizes, decoder_output_size {1..8}, estimation dropout; with F or W:
  fwe size {8, .., 128}.
* Top10NN: image and decoder dropout, img_feature_size {32, .., 512}, decoder sizes; with E:
  estimation sizes, decoder_output_size, estimation dropout; with F or W: fwe size.
* VGG-LSTM: lstm dropout {0, .., 0.4}, hidden size {32, .., 512}, scalar embedding sizes
  {8, .., 256} (force_dim with F, width_dim with W, elastic_dim and hertz_dim with E).
"""

from __future__ import annotations

import builtins
import contextlib
import hashlib
import json
import logging
import shutil
import time
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd
import yaml

from tactile_compliance.config import (
    ConfigError,
    ExperimentConfig,
    config_from_dict,
    config_to_dict,
    load_config,
    save_config,
)
from tactile_compliance.models.inputs import InputStrategy
from tactile_compliance.progress import ProgressBar, progress_bar
from tactile_compliance.runs.layout import config_hash
from tactile_compliance.training.cluster import dask_client, limit_threads
from tactile_compliance.training.experiment import precompute_features
from tactile_compliance.training.grid import expand_experiment, load_experiment

__all__ = [
    "BalanceObjective",
    "TrialObjective",
    "TuneError",
    "TuneResult",
    "base_config",
    "search_space",
    "trial_overrides",
    "tune",
    "tune_balance",
]

MODELS = ("top10nn", "vgg_lstm", "res_tf")
LR_CHOICES = tuple(float(f"{i}e-{j}") for j in range(2, 7) for i in range(1, 10))
GAMMA_CHOICES = ("none", *(f"{0.95 + 0.005 * k:.3f}" for k in range(10)))
BATCH_CHOICES = (8, 16, 32, 64, 128)
DROPOUT_CHOICES = (0.0, 0.1, 0.2, 0.3, 0.4)
SIZES_CHOICES = ("32-32-16", "64-64-32", "128-128-64", "256-256-128", "512-512-256")
DIM_CHOICES = (128, 256, 512, 1024)
FWE_CHOICES = (8, 16, 32, 64, 128)
SCALAR_DIM_CHOICES = (8, 16, 32, 64, 128, 256)
POW2_32_512 = (32, 64, 128, 256, 512)
#: Hyperparameters whose categorical value is a layer-size list written "a-b-c".
SIZE_KEYS = ("decoder_sizes", "estimation_sizes")
#: Cost SMAC records for a trial that raised (validation N-MSE of labels in [0, 1] is <= 1).
CRASH_COST = 1.0


class TuneError(RuntimeError):
    """Tuning cannot start or continue (SMAC missing, an incompatible earlier run, ...)."""


def _require_smac() -> Any:
    try:
        import smac
    except ImportError as exc:
        raise TuneError(
            "tuning needs SMAC3: pip install 'tactile-compliance[hpo]' (smac>=2.2,<3)"
        ) from exc
    return smac


# =========================================================================== search spaces
def search_space(model: str, inputs: str = "ALL", seed: int = 0) -> Any:
    """The paper's search space of ``model`` for input strategy ``inputs`` (ConfigSpace).

    Hyperparameter names are the dotted config keys they set (``training.lr``,
    ``model.hparams.num_layers``), so a configuration maps onto overrides one to one.
    """
    from ConfigSpace import Categorical, ConfigurationSpace

    model = model.strip().lower()
    if model not in MODELS:
        raise ConfigError(f"unknown model {model!r}; tunable: {', '.join(MODELS)}")
    strategy = InputStrategy.parse(_canonical_inputs(inputs))
    uses_f, uses_w, uses_e = strategy.uses_force, strategy.uses_width, strategy.uses_estimates

    def cat(name: str, items: Sequence[Any], default: Any = None) -> Any:
        return Categorical(name, list(items), default=default if default in items else items[0])

    hp = "model.hparams."
    space = [
        cat("training.lr", LR_CHOICES, 1e-4),
        cat("training.gamma", GAMMA_CHOICES, "none"),
        cat("training.batch_size", BATCH_CHOICES, 32),
    ]
    if model == "res_tf":
        space += [
            cat(hp + "video_dropout", DROPOUT_CHOICES, 0.1),
            cat(hp + "decoder_dropout", DROPOUT_CHOICES, 0.3),
            cat(hp + "num_layers", (2, 3, 4, 5, 6), 4),
            cat(hp + "num_heads", (1, 2, 4, 8, 16), 2),
            cat(hp + "embedding_dim", DIM_CHOICES, 256),
            cat(hp + "output_dim", DIM_CHOICES, 512),
            cat(hp + "decoder_sizes", SIZES_CHOICES, "512-512-256"),
        ]
        if uses_e:
            space += [
                cat(hp + "estimation_sizes", SIZES_CHOICES, "64-64-32"),
                cat(hp + "decoder_output_size", tuple(range(1, 9)), 3),
                cat(hp + "estimation_dropout", DROPOUT_CHOICES, 0.1),
            ]
    elif model == "top10nn":
        space += [
            cat(hp + "image_dropout", DROPOUT_CHOICES, 0.3),
            cat(hp + "decoder_dropout", DROPOUT_CHOICES, 0.3),
            cat(hp + "img_feature_size", POW2_32_512, 128),
            cat(hp + "decoder_sizes", SIZES_CHOICES, "512-512-256"),
        ]
        if uses_e:
            space += [
                cat(hp + "estimation_sizes", SIZES_CHOICES, "64-64-32"),
                cat(hp + "decoder_output_size", tuple(range(1, 9)), 3),
                cat(hp + "estimation_dropout", DROPOUT_CHOICES, 0.3),
            ]
    else:  # vgg_lstm
        space += [
            cat(hp + "lstm_dropout", DROPOUT_CHOICES, 0.2),
            cat(hp + "hidden_size", POW2_32_512, 256),
        ]
        if uses_f:
            space.append(cat(hp + "force_dim", SCALAR_DIM_CHOICES, 32))
        if uses_w:
            space.append(cat(hp + "width_dim", SCALAR_DIM_CHOICES, 32))
        if uses_e:
            space += [
                cat(hp + "elastic_dim", SCALAR_DIM_CHOICES, 32),
                cat(hp + "hertz_dim", SCALAR_DIM_CHOICES, 32),
            ]
    if model in ("res_tf", "top10nn") and (uses_f or uses_w):
        space.append(cat(hp + "fwe_size", FWE_CHOICES, 32))
    configspace = ConfigurationSpace(seed=seed)
    configspace.add(space)
    return configspace


def _canonical_inputs(inputs: str) -> str:
    """The paper's name of an input strategy; an unknown name is a ConfigError."""
    try:
        return InputStrategy.parse(inputs).value
    except ValueError as exc:
        raise ConfigError(str(exc)) from exc


def _plain(value: Any) -> Any:
    """numpy scalars (what ConfigSpace returns) -> Python scalars."""
    return value.item() if hasattr(value, "item") else value


def trial_values(config: Mapping[str, Any]) -> dict[str, Any]:
    """A SMAC configuration as ``{dotted key: config value}`` (sizes as lists, gamma None)."""
    values: dict[str, Any] = {}
    for name, raw in dict(config).items():
        value = _plain(raw)
        if name == "training.gamma":
            value = None if value == "none" else float(value)
        elif name.rsplit(".", 1)[-1] in SIZE_KEYS:
            value = [int(v) for v in str(value).split("-")]
        values[name] = value
    return values


def trial_overrides(config: Mapping[str, Any]) -> list[str]:
    """A SMAC configuration as ``dotted.key=value`` overrides for ``config_from_dict``."""
    return [f"{k}={json.dumps(v)}" for k, v in trial_values(config).items()]


# =========================================================================== base configs
def base_config(
    config: str | Path,
    model: str,
    inputs: str = "ALL",
    *,
    quick: bool = False,
    store: str | Path | None = None,
    overrides: Iterable[str] = (),
    seed: int | None = None,
    condition: str | None = None,
) -> ExperimentConfig:
    """The configuration a tuning trial starts from.

    ``config`` is a config (preset or file): ``model``, ``inputs`` and ``overrides`` are
    applied to it; or an experiment (preset or file): the configuration of its first cell
    with this model and input strategy (and ``condition`` when given), so that e.g.
    ``tune res_tf --config table1 --quick`` trains with the quick grid's CPU settings.
    """
    inputs = _canonical_inputs(inputs)
    spec = load_experiment(config, quick=quick)
    if spec.grid or spec.rules or spec.set:
        where = [f"model.name={model}", f"inputs={inputs}"]
        if condition:
            where.append(f"split.condition={condition}")
        cells = expand_experiment(
            spec,
            seeds=[seed] if seed is not None else spec.seeds[:1],
            store=store,
            overrides=overrides,
            where=where,
        )
        if not cells:
            raise ConfigError(
                f"experiment {spec.name} has no cell with model {model} and inputs {inputs}"
                + (f" and condition {condition}" if condition else "")
            )
        return cells[0].cfg
    extra = [f"model.name={model}", f"inputs={inputs}"]
    if store is not None:
        extra.append(f"data.store={json.dumps(str(Path(store).resolve()))}")
    if seed is not None:
        extra.append(f"seed={seed}")
    if condition:
        extra.append(f"split.condition={condition}")
    return load_config(spec.config, [*extra, *overrides])


# =========================================================================== objectives
def _train_trial(cfg: ExperimentConfig, trials_dir: str) -> dict[str, Any]:
    """One trial = one training run; weights are deleted afterwards (results are kept)."""
    from tactile_compliance.training.experiment import _quiet_training_warnings
    from tactile_compliance.training.train import train

    _quiet_training_warnings()
    run_dir = Path(trials_dir) / config_hash(cfg)
    result = train(cfg, run_dir=run_dir, progress=False)
    # A trial's weights are never used again (metrics.json makes the trial idempotent),
    # and 132 trials x a VGG16 checkpoint would fill the disk.
    shutil.rmtree(run_dir / "checkpoints", ignore_errors=True)
    (run_dir / "best.pt").unlink(missing_ok=True)
    return result


@dataclass
class TrialObjective:
    """SMAC target function: validation N-MSE of ``base`` + a configuration, budget epochs.

    A picklable object (Dask ships it to the workers); the training seed is the base
    config's, so trials differ only in their hyperparameters (SMAC is deterministic here).
    """

    base: dict[str, Any]
    trials_dir: str
    threads: int | None = None

    @property
    def __code__(self) -> Any:
        # SMAC fingerprints a target function by its bytecode (to decide whether an old run
        # may be continued); give it the bytecode of __call__.
        return type(self).__call__.__code__

    def config_for(self, config: Mapping[str, Any], budget: float | None) -> ExperimentConfig:
        """The experiment config of one trial."""
        extra = trial_overrides(config)
        if budget is not None:
            extra.append(f"training.max_epochs={max(1, round(float(budget)))}")
        return config_from_dict(self.base, extra, "tuning trial")

    def __call__(self, config: Any, seed: int = 0, budget: float | None = None) -> float:
        del seed  # deterministic: the base config's seed
        limit_threads(self.threads)
        result = _train_trial(self.config_for(config, budget), self.trials_dir)
        return float(result["best_val_nmse"])


@dataclass
class BalanceObjective:
    """SMAC target function of ``tune_balance``: mean validation N-MSE over the models."""

    bases: list[dict[str, Any]]
    trials_dir: str
    epochs: int
    threads: int | None = None

    @property
    def __code__(self) -> Any:
        return type(self).__call__.__code__

    def configs_for(self, t_balance: float) -> list[ExperimentConfig]:
        """One config per model with balanced sampling at ``t_balance`` and fixed epochs."""
        extra = [
            "sampling.strategy=balanced",
            f"sampling.t_balance={t_balance}",
            f"training.max_epochs={self.epochs}",
        ]
        return [config_from_dict(base, extra, "balance trial") for base in self.bases]

    def __call__(self, config: Any, seed: int = 0) -> float:
        del seed
        limit_threads(self.threads)
        t_balance = int(_plain(config["t_balance_percent"])) / 100
        costs = [
            float(_train_trial(cfg, self.trials_dir)["best_val_nmse"])
            for cfg in self.configs_for(t_balance)
        ]
        return sum(costs) / len(costs)


# =========================================================================== running SMAC
@dataclass
class TuneResult:
    """What a tuning run found and where it wrote it."""

    name: str
    output_dir: Path
    best: dict[str, Any]
    best_cost: float
    best_budget: float | None
    trials: int
    config_path: Path
    tuned_path: Path
    trials_path: Path
    wall_time_s: float = 0.0
    extra_paths: list[Path] = field(default_factory=list)

    def format(self) -> str:
        """A printable summary."""
        budget = f" at {self.best_budget:g} epochs" if self.best_budget is not None else ""
        lines = [
            f"{self.name}: {self.trials} trials, best validation N-MSE {self.best_cost:.5f}"
            f"{budget} ({self.wall_time_s:.1f} s)",
            *(f"  {k} = {v}" for k, v in self.best.items()),
            f"Config: {self.config_path}",
            f"Tuned values: {self.tuned_path}",
            f"All trials: {self.trials_path}",
            *(f"Also: {p}" for p in self.extra_paths),
        ]
        return "\n".join(lines)


def _search_name(prefix: str, *parts: Any) -> str:
    import smac

    blob = json.dumps([*parts, smac.version], sort_keys=True, default=str)
    return f"{prefix}-{hashlib.sha256(blob.encode()).hexdigest()[:10]}"


def _reconcile_previous_run(scenario: Any) -> None:
    """Let SMAC continue an earlier run that differs only in its trial budget.

    SMAC continues a run only when the saved scenario equals the new one; otherwise it asks
    on stdin. The directory name already pins everything that defines the search, so the
    only differences left are the number of trials and time limits: write the new values
    into the saved scenario (and un-finish it when more trials are asked for).
    """
    directory = Path(scenario.output_directory)
    saved_path = directory / "scenario.json"
    if not saved_path.exists():
        return
    _forget_unfinished_trials(directory)
    saved = json.loads(saved_path.read_text())
    changed = False
    for key in ("n_trials", "walltime_limit", "cputime_limit", "n_workers"):
        new = getattr(scenario, key)
        if key in saved and saved[key] != new:
            saved[key] = new
            changed = True
    if not changed:
        return
    saved_path.write_text(json.dumps(saved, indent=4))
    optimization = directory / "optimization.json"
    if optimization.exists():
        state = json.loads(optimization.read_text())
        state["finished"] = False
        optimization.write_text(json.dumps(state, indent=2))


def _forget_unfinished_trials(directory: Path) -> None:
    """Drop trials an interrupted SMAC run saved as RUNNING, so that they run again.

    SMAC saves a trial as RUNNING when it is handed out; if the process dies before the
    result comes back, a resumed SMAC would count it as a trial forever without a result.
    Dropped, it is proposed again, and its run directory resumes from its checkpoint.
    """
    from smac.runhistory.enumerations import StatusType

    path = directory / "runhistory.json"
    if not path.exists():
        return
    try:
        history = json.loads(path.read_text())
        entries = history["data"]
    except (OSError, ValueError, KeyError):
        return  # SMAC itself reports an unreadable history
    running = [e for e in entries if e.get("status") == StatusType.RUNNING]
    if not running:
        return
    history["data"] = [e for e in entries if e.get("status") != StatusType.RUNNING]
    stats = history.get("stats", {})
    stats["submitted"] = max(0, int(stats.get("submitted", 0)) - len(running))
    stats["running"] = 0
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(history, indent=2))
    tmp.replace(path)


def _initial_design_size(scenario: Any) -> int:
    """SMAC's default initial-design size for the *first* run of this search."""
    saved = Path(scenario.output_directory) / "scenario.json"
    if saved.exists():
        with contextlib.suppress(OSError, ValueError, KeyError, TypeError):
            return int(json.loads(saved.read_text())["_meta"]["initial_design"]["n_configs"])
    n_params = len(list(scenario.configspace.values()))
    return int(max(1, min(10 * n_params, 0.25 * scenario.n_trials)))


@contextlib.contextmanager
def _no_interactive_prompt(directory: Path) -> Iterator[None]:
    """SMAC asks on stdin when an old run differs; fail with a clear error instead."""

    def refuse(prompt: str = "") -> str:
        raise TuneError(
            f"{directory} holds a SMAC run that cannot be continued with these settings; "
            "pass overwrite=True (--overwrite) or another output directory"
        )

    original = builtins.input
    builtins.input = refuse
    try:
        yield
    finally:
        builtins.input = original


def _progress_callback(bar: ProgressBar) -> Any:
    """A SMAC callback that moves ``bar``: trials finished and the best cost so far."""
    from smac.callback import Callback

    class _Bar(Callback):
        best = float("inf")

        def on_start(self, smbo: Any) -> None:
            bar.update(completed=smbo.runhistory.finished)

        def on_tell_end(self, smbo: Any, info: Any, value: Any) -> bool | None:
            self.best = min(self.best, float(value.cost))
            bar.update(completed=smbo.runhistory.finished, best=f"{self.best:.5f}")
            return None

    return _Bar()


def _trials_table(facade: Any, decode: bool = True) -> pd.DataFrame:
    runhistory = facade.runhistory
    rows = []
    for key, value in runhistory.items():
        config = runhistory.get_config(key.config_id)
        values = trial_values(config) if decode else {k: _plain(v) for k, v in dict(config).items()}
        rows.append(
            {
                "config_id": key.config_id,
                "budget": key.budget,
                "cost": value.cost,
                "status": value.status.name if hasattr(value.status, "name") else value.status,
                "time_s": round(float(value.time), 2),
                **values,
            }
        )
    return pd.DataFrame(rows)


def _incumbent_cost(facade: Any, incumbent: Any) -> tuple[float, float | None]:
    """Cost of the incumbent at the highest budget it was evaluated on."""
    runhistory = facade.runhistory
    config_id = runhistory.get_config_id(incumbent)
    best: tuple[float, float | None] = (float("inf"), None)
    highest = -1.0
    for key, value in runhistory.items():
        if key.config_id != config_id:
            continue
        budget = key.budget if key.budget is not None else 0.0
        if budget >= highest:
            highest = budget
            best = (float(value.cost), key.budget)
    return best


def _write_yaml(path: Path, header: str, data: Mapping[str, Any]) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    text = header + yaml.safe_dump(dict(data), sort_keys=False, default_flow_style=None)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(path)
    return path


def _check_store(base: ExperimentConfig) -> None:
    """Fail before SMAC starts (not in its first trial) when the store is missing."""
    if not base.data.store or not Path(base.data.store).is_dir():
        raise ConfigError(
            f"store not found: {base.data.store or '(data.store not set)'}; pass --store PATH"
        )


def _prepare_features(base: ExperimentConfig, client: Any, threads: int | None) -> None:
    """Compute the frozen-backbone feature cache once, before trials run in parallel."""
    if not base.model.freeze_backbone:
        return
    if client is not None:
        client.submit(precompute_features, [config_to_dict(base)], threads, pure=False).result()
    else:
        precompute_features([config_to_dict(base)], None)


def _run_smac(
    facade_cls: Any,
    scenario: Any,
    objective: Any,
    *,
    intensifier: Any = None,
    client: Any,
    overwrite: bool,
    progress: bool,
    label: str,
    trials: int,
) -> Any:
    logging.getLogger("smac").setLevel(logging.ERROR)
    _reconcile_previous_run(scenario)
    kwargs: dict[str, Any] = {"intensifier": intensifier} if intensifier is not None else {}
    # SMAC sizes its random initial design from n_trials; pin it to the first run's size
    # so that a search extended with more trials is still the same search.
    kwargs["initial_design"] = facade_cls.get_initial_design(
        scenario, n_configs=_initial_design_size(scenario), max_ratio=1.0
    )
    with progress_bar(
        label,
        trials,
        progress,
        fields={"best": "-"},
        fields_format="best {task.fields[best]}",
        eta=False,
    ) as bar:
        with _no_interactive_prompt(Path(scenario.output_directory)):
            facade = facade_cls(
                scenario,
                objective,
                overwrite=overwrite,
                dask_client=client,
                logging_level=False,
                callbacks=[_progress_callback(bar)],
                **kwargs,
            )
        incumbent = facade.optimize()
    if isinstance(incumbent, list):  # several incumbents only with several objectives
        incumbent = incumbent[0]
    if incumbent is None:
        raise TuneError(f"{label}: no trial finished; see {scenario.output_directory}")
    return facade, incumbent


def _tuning_dir(output_dir: str | Path | None, label: str) -> Path:
    """Where a search writes (default ``tuning/LABEL``), absolute."""
    out = Path(output_dir) if output_dir is not None else Path("tuning") / label
    return out.expanduser().resolve()


@contextlib.contextmanager
def _trial_cluster(
    workers: int, scheduler: str | None, client: Any, threads: int | None
) -> Iterator[tuple[Any, int | None]]:
    """(Dask client or None for serial trials, torch threads per trial).

    Parallel trials run single-threaded unless told otherwise (one trial per core).
    """
    if workers <= 1 and scheduler is None and client is None:
        yield None, threads
        return
    with dask_client(workers, scheduler, client) as dask:
        yield dask, 1 if threads is None else threads


def tune(
    model: str,
    inputs: str = "ALL",
    *,
    config: str | Path = "default",
    quick: bool = False,
    store: str | Path | None = None,
    overrides: Iterable[str] = (),
    condition: str | None = None,
    trials: int = 132,
    min_epochs: int = 5,
    max_epochs: int = 50,
    eta: int = 3,
    seed: int = 0,
    workers: int = 1,
    scheduler: str | None = None,
    client: Any = None,
    output_dir: str | Path | None = None,
    overwrite: bool = False,
    threads: int | None = None,
    progress: bool = True,
) -> TuneResult:
    """Tune one model for one input strategy with SMAC3 (Hyperband over epochs).

    Args:
        model: ``top10nn``, ``vgg_lstm`` or ``res_tf``.
        inputs: input strategy whose search space is used (Image, ImageF, ImageFW, ALL).
        config: base config or experiment (preset or file); see :func:`base_config`.
        quick: with an experiment as ``config``, use its quick variant.
        store: GraspStore (``data.store``).
        overrides: ``dotted.key=value`` applied to the base config.
        condition: seen / unseen (default: the base config's).
        trials: SMAC trials (a trial = one configuration at one budget).
        min_epochs, max_epochs: Hyperband budget range (epochs).
        eta: Hyperband's halving rate.
        seed: training seed of every trial and SMAC's seed.
        workers: parallel trials on a local Dask cluster (1: in this process).
        scheduler: address or scheduler-file of a running Dask scheduler.
        client: an existing ``distributed.Client`` (Python API).
        output_dir: default ``tuning/MODEL-INPUTS`` (``-quick`` appended for quick).
        overwrite: start over instead of continuing an earlier run in ``output_dir``.
        threads: torch threads per trial (default: 1 with Dask, torch's default without).
        progress: show a progress bar.
    """
    smac = _require_smac()
    if not 1 <= min_epochs <= max_epochs:
        raise ConfigError(f"need 1 <= min_epochs <= max_epochs, got {min_epochs}, {max_epochs}")
    if trials < 1:
        raise ConfigError(f"trials must be >= 1, got {trials}")
    started = time.perf_counter()
    inputs = _canonical_inputs(inputs)
    model = model.strip().lower()
    base = base_config(
        config,
        model,
        inputs,
        quick=quick,
        store=store,
        overrides=overrides,
        seed=seed,
        condition=condition,
    )
    if scheduler is None and client is None:
        _check_store(base)
    label = f"{model}-{inputs}" + ("-quick" if quick else "")
    out = _tuning_dir(output_dir, label)
    base_dict = config_to_dict(base)
    base_dict["output_dir"] = str(out / "trials")
    configspace = search_space(model, inputs, seed)
    name = _search_name(
        "smac", base_dict, str(configspace), min_epochs, max_epochs, eta, seed, "tune"
    )
    scenario = smac.Scenario(
        configspace,
        name=name,
        output_directory=out / "smac",
        deterministic=True,
        n_trials=trials,
        min_budget=min_epochs,
        max_budget=max_epochs,
        seed=seed,
        crash_cost=CRASH_COST,
    )
    with _trial_cluster(workers, scheduler, client, threads) as (dask, threads):
        _prepare_features(base, dask, threads)
        objective = TrialObjective(base_dict, str(out / "trials"), threads)
        facade, incumbent = _run_smac(
            smac.MultiFidelityFacade,
            scenario,
            objective,
            intensifier=smac.MultiFidelityFacade.get_intensifier(scenario, eta=eta),
            client=dask,
            overwrite=overwrite,
            progress=progress,
            label=f"tune {label}",
            trials=trials,
        )
    cost, budget = _incumbent_cost(facade, incumbent)
    best_values = trial_values(incumbent)
    # The tuned config trains for the base config's epochs, not the search budget.
    best_cfg = config_from_dict(
        base_dict,
        [*trial_overrides(incumbent), f"output_dir={json.dumps(str(Path('runs') / label))}"],
        "tuned configuration",
    )
    config_path = save_config(best_cfg, out / "best.yaml")
    header = (
        f"# Tuned by `tactile-compliance tune {model} --inputs {inputs}`: validation N-MSE "
        f"{cost:.5f} at {budget} epochs.\n# Dotted overrides; use with `include:` in an "
        "experiment rule, or --set each line.\n"
    )
    tuned_path = _write_yaml(out / "tuned.yaml", header, best_values)
    table = _trials_table(facade)
    trials_path = out / "trials.csv"
    table.to_csv(trials_path, index=False)
    result = TuneResult(
        name=f"tune {label}",
        output_dir=out,
        best=best_values,
        best_cost=cost,
        best_budget=budget,
        trials=len(table),
        config_path=config_path,
        tuned_path=tuned_path,
        trials_path=trials_path,
        wall_time_s=round(time.perf_counter() - started, 2),
    )
    return result  # the caller prints result.format() (the CLI does)


def tune_balance(
    config: str | Path = "table2",
    *,
    quick: bool = False,
    models: Sequence[str] = MODELS,
    inputs: str = "ALL",
    condition: str | None = "seen",
    epochs: int = 10,
    trials: int = 30,
    store: str | Path | None = None,
    overrides: Iterable[str] = (),
    seed: int = 0,
    workers: int = 1,
    scheduler: str | None = None,
    client: Any = None,
    output_dir: str | Path | None = None,
    overwrite: bool = False,
    threads: int | None = None,
    progress: bool = True,
) -> TuneResult:
    """Tune ``sampling.t_balance`` in [0, 1] (step 0.01) with SMAC3's BO facade.

    Cost of a value: the mean, over ``models``, of the best validation N-MSE after
    ``epochs`` epochs of balanced training. Note that validation is balanced too
    (``sampling.balance_validation``, as in the paper), so the cost also depends on how
    the validation set is oversampled; pass ``--set sampling.balance_validation=false``
    to score on the untouched validation split.

    Writes ``OUT/tuned.yaml`` (``sampling.strategy``/``t_balance``), ``OUT/best-MODEL.yaml``
    per model, and, when ``config`` is an experiment NAME, ``OUT/NAME-tuned.yaml``: that
    experiment with the tuned value (``experiment OUT/NAME-tuned.yaml``, plus ``--quick``
    for its quick variant).
    """
    smac = _require_smac()
    from ConfigSpace import ConfigurationSpace, Integer

    if epochs < 1 or trials < 1:
        raise ConfigError(f"epochs and trials must be >= 1, got {epochs}, {trials}")
    started = time.perf_counter()
    inputs = _canonical_inputs(inputs)
    models = [m.strip().lower() for m in models]
    bases = [
        base_config(
            config,
            m,
            inputs,
            quick=quick,
            store=store,
            overrides=overrides,
            seed=seed,
            condition=condition,
        )
        for m in models
    ]
    if scheduler is None and client is None:
        for base in bases:
            _check_store(base)
    label = "balance" + ("-quick" if quick else "")
    out = _tuning_dir(output_dir, label)
    base_dicts = []
    for base in bases:
        data = config_to_dict(base)
        data["output_dir"] = str(out / "trials")
        base_dicts.append(data)
    configspace = ConfigurationSpace(seed=seed)
    configspace.add(Integer("t_balance_percent", (0, 100), default=50))
    name = _search_name("smac", base_dicts, epochs, seed, "balance")
    scenario = smac.Scenario(
        configspace,
        name=name,
        output_directory=out / "smac",
        deterministic=True,
        n_trials=trials,
        seed=seed,
        crash_cost=CRASH_COST,
    )
    with _trial_cluster(workers, scheduler, client, threads) as (dask, threads):
        for base in bases:
            _prepare_features(base, dask, threads)
        objective = BalanceObjective(base_dicts, str(out / "trials"), epochs, threads)
        facade, incumbent = _run_smac(
            smac.HyperparameterOptimizationFacade,
            scenario,
            objective,
            intensifier=None,
            client=dask,
            overwrite=overwrite,
            progress=progress,
            label=f"tune-balance{' (quick)' if quick else ''}",
            trials=trials,
        )
    cost, _ = _incumbent_cost(facade, incumbent)
    t_balance = int(_plain(incumbent["t_balance_percent"])) / 100
    best = {"sampling.strategy": "balanced", "sampling.t_balance": t_balance}
    header = (
        f"# Tuned by `tactile-compliance tune-balance`: mean validation N-MSE {cost:.5f} "
        f"of {', '.join(models)} after {epochs} epochs.\n"
    )
    tuned_path = _write_yaml(out / "tuned.yaml", header, best)
    extra_paths = []
    for base in bases:
        cfg = config_from_dict(
            config_to_dict(base),
            [
                "sampling.strategy=balanced",
                f"sampling.t_balance={t_balance}",
                f"output_dir={Path('runs') / label}",
            ],
        )
        extra_paths.append(save_config(cfg, out / f"best-{cfg.model.name}.yaml"))
    config_path = extra_paths[0]
    spec = load_experiment(config, quick=False)
    if spec.grid or spec.rules or spec.set:
        ref = str(config) if spec.origin.startswith("experiment preset") else spec.origin
        experiment = {
            "description": f"{spec.description} (t_balance tuned: {t_balance})",
            "extends": ref,
            "set": best,
        }
        # Named after the experiment: its runs go to runs/NAME-tuned(-quick).
        config_path = _write_yaml(out / f"{spec.name}-tuned.yaml", header, experiment)
    table = _trials_table(facade, decode=False)
    trials_path = out / "trials.csv"
    table.to_csv(trials_path, index=False)
    result = TuneResult(
        name=f"tune-balance {', '.join(models)}",
        output_dir=out,
        best={"sampling.t_balance": t_balance},
        best_cost=cost,
        best_budget=None,
        trials=len(table),
        config_path=config_path,
        tuned_path=tuned_path,
        trials_path=trials_path,
        wall_time_s=round(time.perf_counter() - started, 2),
        extra_paths=[p for p in extra_paths if p != config_path],
    )
    return result  # the caller prints result.format() (the CLI does)
