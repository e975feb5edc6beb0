"""Hyperparameter tuning with SMAC3: the models' declared search spaces, epochs as budget.

* :func:`tune` searches one model's hyperparameters for one input strategy with SMAC's
  multi-fidelity facade (Hyperband over epochs), as in the paper. Every trial is one call
  of the training path (:func:`tactile_compliance.training.train.train`) with
  ``training.max_epochs`` set to the trial's budget. Any registered model can be tuned:
  its class declares the search space (``hpo_space``, see ``models.settings``).
* :func:`tune_balance` searches ``sampling.t_balance`` in [0, 1] (step 0.01), cost the
  mean validation N-MSE of the models after a fixed number of epochs.

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

Modules: ``space`` (the ConfigSpace view of a search space), ``objectives`` (what a
trial trains), ``smac_run`` (running, resuming and reading SMAC), ``drivers`` (``tune``,
``tune_balance`` and the files they write).
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
