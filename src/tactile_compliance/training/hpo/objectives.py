"""What a tuning trial trains: its base configuration and the SMAC target functions.

A trial is one call of the training path (:func:`tactile_compliance.training.train.train`)
on the base config plus the trial's values; its cost is the run's best validation N-MSE.
"""

from __future__ import annotations

import json
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
from tactile_compliance.runs.layout import config_hash
from tactile_compliance.training.cluster import limit_threads
from tactile_compliance.training.experiment import precompute_features
from tactile_compliance.training.grid import expand_experiment, load_experiment
from tactile_compliance.training.hpo.space import canonical_inputs, plain, trial_overrides

__all__ = [
    "BalanceObjective",
    "TrialObjective",
    "base_config",
    "check_store",
    "prepare_features",
]


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
    if not spec.is_plain_config:
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
    """A SMAC target function: a picklable object (Dask ships it to the workers).

    ``__call__`` bodies are fingerprinted by SMAC (below): changing one makes SMAC refuse
    to continue searches started before the change.
    """

    @property
    def __code__(self) -> Any:
        # SMAC fingerprints a target function by its bytecode (to decide whether an old run
        # may be continued); give it the bytecode of __call__.
        return type(self).__call__.__code__


@dataclass
class TrialObjective(_Objective):
    """SMAC target function: validation N-MSE of ``base`` + a configuration, budget epochs.

    The training seed is the base config's, so trials differ only in their
    hyperparameters (SMAC is deterministic here).
    """

    base: dict[str, Any]
    trials_dir: str
    threads: int | None = None

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
class BalanceObjective(_Objective):
    """SMAC target function of ``tune_balance``: mean validation N-MSE over the models."""

    bases: list[dict[str, Any]]
    trials_dir: str
    epochs: int
    threads: int | None = None

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
        t_balance = int(plain(config["t_balance_percent"])) / 100
        costs = [
            float(_train_trial(cfg, self.trials_dir)["best_val_nmse"])
            for cfg in self.configs_for(t_balance)
        ]
        return sum(costs) / len(costs)
