"""What a tuning trial trains: its base configuration and the SMAC target functions.

A trial is one ``train`` call; its cost is the validation N-MSE of its last or best
epoch. See docs/experiments.md, "Tuning (SMAC3)", for why ``last`` is the default.
"""

from __future__ import annotations

import csv
import json
import math
import shutil
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tactile_compliance.config import (
    ConfigError,
    ExperimentConfig,
    config_from_dict,
    config_to_dict,
    load_config,
)
from tactile_compliance.runs.layout import EPOCH_LOG, config_hash, read_epoch_log
from tactile_compliance.training.cluster import limit_threads
from tactile_compliance.training.experiment import precompute_features
from tactile_compliance.training.experiment_file import expand_experiment, load_experiment
from tactile_compliance.training.hpo.space import canonical_inputs, plain, trial_overrides

__all__ = [
    "DEFAULT_OBJECTIVE",
    "OBJECTIVES",
    "BalanceObjective",
    "TrialObjective",
    "base_config",
    "check_objective",
    "check_store",
    "last_epoch_val_nmse",
    "prepare_features",
    "trial_cost",
]

#: What a trial's cost is: the validation N-MSE of its "last" epoch (the published code)
#: or of its "best" epoch.
OBJECTIVES = ("last", "best")
DEFAULT_OBJECTIVE = "last"


def check_objective(objective: str) -> str:
    """``objective`` if it is one of :data:`OBJECTIVES`, else a ConfigError."""
    if objective not in OBJECTIVES:
        raise ConfigError(f"objective must be one of {', '.join(OBJECTIVES)}, got {objective!r}")
    return objective


def last_epoch_val_nmse(run_dir: str | Path) -> float:
    """The validation N-MSE of a run's last validated epoch, from its epoch log.

    A ValueError when there is no epoch log or no finite validation N-MSE in it.
    """
    path = Path(run_dir) / EPOCH_LOG
    try:
        rows = read_epoch_log(path)
    except (OSError, csv.Error, UnicodeDecodeError) as err:
        raise ValueError(f"{path}: cannot read the epoch log ({err})") from err
    last: tuple[int, float] | None = None
    for epoch, row in rows:
        try:
            value = float(row.get("val_nmse") or "nan")
        except ValueError:
            continue
        # Train and validation values are separate lines of one epoch; a later line of the
        # same epoch wins (a resumed run rewrites nothing it kept, so there is one).
        if math.isfinite(value) and (last is None or epoch >= last[0]):
            last = (epoch, value)
    if last is None:
        raise ValueError(f"{path}: no epoch with a validation N-MSE")
    return last[1]


def trial_cost(result: Mapping[str, Any], objective: str) -> float:
    """A trial's cost: the validation N-MSE of its ``"last"`` or ``"best"`` epoch."""
    if check_objective(objective) == "best":
        return float(result["best_val_nmse"])
    if result.get("last_val_nmse") is not None:
        return float(result["last_val_nmse"])
    return last_epoch_val_nmse(result["run_dir"])


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
    inputs = canonical_inputs(inputs)
    spec = load_experiment(config, quick=quick)
    # The cell an experiment is filtered to, or the overrides of a plain config.
    chosen = [f"model.name={model}", f"inputs={inputs}"]
    if condition:
        chosen.append(f"split.condition={condition}")
    if not spec.is_plain_config:
        cells = expand_experiment(
            spec,
            seeds=[seed] if seed is not None else spec.seeds[:1],
            store=store,
            overrides=overrides,
            where=chosen,
        )
        if not cells:
            raise ConfigError(
                f"experiment {spec.name} has no cell with model {model} and inputs {inputs}"
                + (f" and condition {condition}" if condition else "")
            )
        return cells[0].cfg
    if store is not None:
        chosen.append(f"data.store={json.dumps(str(Path(store).resolve()))}")
    if seed is not None:
        chosen.append(f"seed={seed}")
    return load_config(spec.config, [*chosen, *overrides])


def check_store(base: ExperimentConfig) -> None:
    """Fail before SMAC starts (not in its first trial) when the store is missing."""
    if not base.data.store or not Path(base.data.store).is_dir():
        raise ConfigError(
            f"store not found: {base.data.store or '(data.store not set)'}; pass --store PATH"
        )


def prepare_features(base: ExperimentConfig, client: Any, threads: int | None) -> None:
    """Compute the frozen-backbone feature cache once, before trials run in parallel."""
    if not base.model.freeze_backbone:
        return
    if client is not None:
        client.submit(precompute_features, [config_to_dict(base)], threads, pure=False).result()
    else:
        precompute_features([config_to_dict(base)], None)


def _objective_overrides(objective: str) -> list[str]:
    """Scored on its last epoch, a trial trains its whole budget (as the published ones)."""
    return ["training.patience=0"] if check_objective(objective) == "last" else []


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
class _Objective:
    """A SMAC target function: a picklable object (Dask ships it to the workers)."""

    @property
    def __code__(self) -> Any:
        # SMAC fingerprints a target function by its bytecode (to decide whether an old run
        # may be continued): changing a __call__ body makes it refuse older searches.
        return type(self).__call__.__code__


@dataclass
class TrialObjective(_Objective):
    """SMAC target function: validation N-MSE of ``base`` + a configuration, budget epochs.

    The training seed is the base config's, so trials differ only in their hyperparameters.
    """

    base: dict[str, Any]
    trials_dir: str
    threads: int | None = None
    objective: str = DEFAULT_OBJECTIVE

    def config_for(self, config: Mapping[str, Any], budget: float | None) -> ExperimentConfig:
        """The experiment config of one trial."""
        extra = trial_overrides(config)
        if budget is not None:
            extra.append(f"training.max_epochs={max(1, round(float(budget)))}")
        extra.extend(_objective_overrides(self.objective))
        return config_from_dict(self.base, extra, "tuning trial")

    def __call__(self, config: Any, seed: int = 0, budget: float | None = None) -> float:
        del seed  # deterministic: the base config's seed
        limit_threads(self.threads)
        result = _train_trial(self.config_for(config, budget), self.trials_dir)
        return trial_cost(result, self.objective)


@dataclass
class BalanceObjective(_Objective):
    """SMAC target function of ``tune_balance``: mean validation N-MSE over the models."""

    bases: list[dict[str, Any]]
    trials_dir: str
    epochs: int
    threads: int | None = None
    objective: str = DEFAULT_OBJECTIVE

    def configs_for(self, t_balance: float) -> list[ExperimentConfig]:
        """One config per model with balanced sampling at ``t_balance`` and fixed epochs."""
        extra = [
            "sampling.strategy=balanced",
            f"sampling.t_balance={t_balance}",
            f"training.max_epochs={self.epochs}",
            *_objective_overrides(self.objective),
        ]
        return [config_from_dict(base, extra, "balance trial") for base in self.bases]

    def __call__(self, config: Any, seed: int = 0) -> float:
        del seed
        limit_threads(self.threads)
        t_balance = int(plain(config["t_balance_percent"])) / 100
        costs = [
            trial_cost(_train_trial(cfg, self.trials_dir), self.objective)
            for cfg in self.configs_for(t_balance)
        ]
        return sum(costs) / len(costs)
