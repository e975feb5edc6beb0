"""Hyperparameter tuning with SMAC3: ``tune`` (a model's hyperparameters), ``tune_balance``.

Modules: ``space`` (the ConfigSpace view of a search space), ``objectives`` (what a
trial trains), ``smac_run`` (running, resuming and reading SMAC), ``drivers`` (``tune``,
``tune_balance`` and the files they write). See docs/experiments.md, "Tuning (SMAC3)".
"""

from __future__ import annotations

# Re-exported for callers (and tests) that reach these through this package.
from tactile_compliance.config import ConfigError
from tactile_compliance.runs.layout import config_hash
from tactile_compliance.training.hpo.drivers import TuneResult, tune, tune_balance
from tactile_compliance.training.hpo.objectives import (
    BalanceObjective,
    TrialObjective,
    base_config,
)
from tactile_compliance.training.hpo.smac_run import CRASH_COST, TuneError
from tactile_compliance.training.hpo.space import search_space, trial_overrides, trial_values

__all__ = [
    "CRASH_COST",
    "BalanceObjective",
    "ConfigError",
    "TrialObjective",
    "TuneError",
    "TuneResult",
    "base_config",
    "config_hash",
    "search_space",
    "trial_overrides",
    "trial_values",
    "tune",
    "tune_balance",
]
