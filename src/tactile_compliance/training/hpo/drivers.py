"""The tuning drivers, :func:`tune` and :func:`tune_balance`, and the files they write.

See docs/experiments.md, "Tuning (SMAC3)".
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from tactile_compliance.config import (
    ConfigError,
    ExperimentConfig,
    config_from_dict,
    config_to_dict,
    save_config,
    write_yaml,
)
from tactile_compliance.models import list_models
from tactile_compliance.outputs import atomic_file, claim_output_dir
from tactile_compliance.training.experiment_file import load_experiment
from tactile_compliance.training.hpo.objectives import (
    DEFAULT_OBJECTIVE,
    BalanceObjective,
    TrialObjective,
    base_config,
    check_objective,
    check_store,
    prepare_features,
)
from tactile_compliance.training.hpo.smac_run import (
    CRASH_COST,
    incumbent_cost,
    require_smac,
    run_smac,
    search_name,
    trial_cluster,
    trials_table,
)
from tactile_compliance.training.hpo.space import (
    canonical_inputs,
    plain,
    search_space,
    trial_overrides,
    trial_values,
)

__all__ = [
    "BALANCE_EPOCHS",
    "BALANCE_TRIALS",
    "PAPER_BALANCE_EPOCHS",
    "PAPER_BALANCE_TRIALS",
    "TuneResult",
    "balance_budget",
    "tune",
    "tune_balance",
]

#: tune_balance's default budget: epochs per model and trial, and trials (CPU-sized).
BALANCE_EPOCHS = 10
BALANCE_TRIALS = 30
#: The paper's t_balance budget (published optimize_balance_threshold.py: SMAC's BO facade
#: with 132 trials; each trains every model for 50 epochs).
PAPER_BALANCE_EPOCHS = 50
PAPER_BALANCE_TRIALS = 132

_OBJECTIVE_WORDS = {"last": "last-epoch", "best": "best-epoch"}


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
    objective: str = DEFAULT_OBJECTIVE

    def format(self) -> str:
        """A printable summary."""
        budget = f" at {self.best_budget:g} epochs" if self.best_budget is not None else ""
        scored = _OBJECTIVE_WORDS.get(self.objective, self.objective)
        lines = [
            f"{self.name}: {self.trials} trials, best {scored} validation N-MSE "
            f"{self.best_cost:.5f}{budget} ({self.wall_time_s:.1f} s)",
            *(f"  {k} = {v}" for k, v in self.best.items()),
            f"Config: {self.config_path}",
            f"Tuned values: {self.tuned_path}",
            f"All trials: {self.trials_path}",
            *(f"Also: {p}" for p in self.extra_paths),
        ]
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        """What :meth:`format` shows, for ``--json``."""
        return {
            "name": self.name,
            "objective": self.objective,
            "trials": self.trials,
            "best": self.best,
            "best_cost": self.best_cost,
            "best_budget": self.best_budget,
            "wall_time_s": round(self.wall_time_s, 2),
            "output_dir": str(self.output_dir),
            "config": str(self.config_path),
            "tuned": str(self.tuned_path),
            "trials_csv": str(self.trials_path),
            "also": [str(p) for p in self.extra_paths],
        }


@dataclass
class _Search:
    """What :func:`tune` and :func:`tune_balance` share: where trials start from, where
    the search writes, how it runs, and its result files."""

    label: str
    name: str
    config: str | Path
    quick: bool
    store: str | Path | None
    overrides: Iterable[str]
    seed: int
    condition: str | None
    workers: int
    scheduler: str | None
    client: Any
    output_dir: str | Path | None
    overwrite: bool
    threads: int | None
    progress: bool
    objective: str
    started: float = field(default_factory=time.perf_counter)

    @classmethod
    def of(cls, label: str, name: str, arguments: Mapping[str, Any]) -> _Search:
        """The search ``name`` writing to ``tuning/LABEL`` by default, with the shared
        options out of a driver's arguments (its ``locals()``)."""
        shared = [f.name for f in fields(cls) if f.name not in ("label", "name", "started")]
        return cls(label, name, **{key: arguments[key] for key in shared})

    @property
    def out(self) -> Path:
        """Where the search writes (default ``tuning/LABEL``), absolute."""
        out = Path(self.output_dir) if self.output_dir is not None else Path("tuning") / self.label
        return out.expanduser().resolve()

    def bases(self, models: Sequence[str], inputs: str) -> list[ExperimentConfig]:
        """The base config of each model; the store must exist unless trials run
        elsewhere (a remote scheduler's workers may see other paths)."""
        bases = [
            base_config(
                self.config,
                model,
                inputs,
                quick=self.quick,
                store=self.store,
                overrides=self.overrides,
                seed=self.seed,
                condition=self.condition,
            )
            for model in models
        ]
        if self.scheduler is None and self.client is None:
            for base in bases:
                check_store(base)
        return bases

    def trial_bases(self, bases: Sequence[ExperimentConfig]) -> list[dict[str, Any]]:
        """The base configs as the objectives get them: trials write below ``OUT/trials``."""
        return [{**config_to_dict(base), "output_dir": str(self.out / "trials")} for base in bases]

    def scenario(self, smac: Any, configspace: Any, name: str, **budget: Any) -> Any:
        """SMAC's scenario: deterministic trials, ``budget`` for multi-fidelity."""
        return smac.Scenario(
            configspace,
            name=name,
            output_directory=self.out / "smac",
            deterministic=True,
            seed=self.seed,
            crash_cost=CRASH_COST,
            **budget,
        )

    def run(
        self,
        facade_cls: Any,
        scenario: Any,
        bases: Sequence[ExperimentConfig],
        objective: Callable[[int | None], Any],
        title: str,
        intensifier: Any = None,
    ) -> tuple[Any, Any]:
        """Run (or continue) the search: (the facade, its incumbent). ``objective`` builds
        the target function for the torch threads a trial gets."""
        # The search writes only into a directory it created (or an earlier search's).
        claim_output_dir(self.out, "tune", option="--out")
        cluster = trial_cluster(self.workers, self.scheduler, self.client, self.threads)
        with cluster as (dask, threads):
            for base in bases:
                prepare_features(base, dask, threads)
            return run_smac(
                facade_cls,
                scenario,
                objective(threads),
                intensifier=intensifier,
                client=dask,
                overwrite=self.overwrite,
                progress=self.progress,
                label=title,
                trials=scenario.n_trials,
            )

    def result(
        self,
        facade: Any,
        best: dict[str, Any],
        cost: tuple[float, float | None],
        paths: Sequence[Path],
        decode: bool = True,
    ) -> TuneResult:
        """Write ``OUT/trials.csv`` and sum the search up: ``best`` the tuned values,
        ``cost`` the best cost and its budget, ``paths`` the config to use, the tuned
        values, then any other written files; ``decode``: trials' values as config values."""
        table = trials_table(facade, decode=decode)
        trials_path = self.out / "trials.csv"
        with atomic_file(trials_path) as handle:
            table.to_csv(handle, index=False)
        config_path, tuned_path, *others = paths
        return TuneResult(
            name=self.name,
            output_dir=self.out,
            best=best,
            best_cost=cost[0],
            best_budget=cost[1],
            trials=len(table),
            config_path=config_path,
            tuned_path=tuned_path,
            trials_path=trials_path,
            wall_time_s=round(time.perf_counter() - self.started, 2),
            extra_paths=list(others),
            objective=self.objective,
        )


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
    objective: str = DEFAULT_OBJECTIVE,
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

    The defaults are the paper's search (132 trials, 5-50 epochs, eta 3, last-epoch cost).

    Args:
        model: a registered model (``models.list_models()``); its class declares the
            search space (``hpo_space``).
        inputs: input strategy whose search space is used (Image, ImageF, ImageFW, ALL).
        config: base config or experiment (preset or file); see :func:`base_config`.
        quick: with an experiment as ``config``, use its quick variant.
        store: GraspStore (``data.store``).
        overrides: ``dotted.key=value`` applied to the base config.
        condition: seen / unseen (default: the base config's).
        trials: SMAC trials (a trial = one configuration at one budget).
        min_epochs, max_epochs: Hyperband budget range (epochs).
        eta: Hyperband's halving rate.
        objective: a trial's cost: the validation N-MSE of its ``"last"`` epoch (the
            published code; no early stopping) or of its ``"best"`` one.
        seed: training seed of every trial and SMAC's seed.
        workers: parallel trials on a local Dask cluster (1: in this process).
        scheduler: address or scheduler-file of a running Dask scheduler.
        client: an existing ``distributed.Client`` (Python API).
        output_dir: default ``tuning/MODEL-INPUTS`` (``-quick`` appended for quick).
        overwrite: start over instead of continuing an earlier run in ``output_dir``.
        threads: torch threads per trial (default: 1 with Dask, torch's default without).
    """
    smac = require_smac()
    if not 1 <= min_epochs <= max_epochs:
        raise ConfigError(f"need 1 <= min_epochs <= max_epochs, got {min_epochs}, {max_epochs}")
    if trials < 1:
        raise ConfigError(f"trials must be >= 1, got {trials}")
    check_objective(objective)
    inputs = canonical_inputs(inputs)
    model = model.strip().lower()
    label = f"{model}-{inputs}" + ("-quick" if quick else "")
    search = _Search.of(label, f"tune {label}", locals())
    [base] = search.bases([model], inputs)
    [base_dict] = search.trial_bases([base])
    configspace = search_space(model, inputs, seed)
    name = search_name(
        "smac", base_dict, str(configspace), min_epochs, max_epochs, eta, seed, "tune", objective
    )
    scenario = search.scenario(
        smac, configspace, name, n_trials=trials, min_budget=min_epochs, max_budget=max_epochs
    )
    facade, incumbent = search.run(
        smac.MultiFidelityFacade,
        scenario,
        [base],
        lambda threads: TrialObjective(
            base_dict, str(search.out / "trials"), threads, objective=objective
        ),
        search.name,
        intensifier=smac.MultiFidelityFacade.get_intensifier(scenario, eta=eta),
    )
    cost, budget = incumbent_cost(facade, incumbent)
    best_values = trial_values(incumbent)
    # The tuned config trains for the base config's epochs, not the search budget.
    best_cfg = config_from_dict(
        base_dict,
        [*trial_overrides(incumbent), f"output_dir={json.dumps(str(Path('runs') / label))}"],
        "tuned configuration",
    )
    config_path = save_config(best_cfg, search.out / "best.yaml")
    header = (
        f"# Tuned by `tactile-compliance tune {model} --inputs {inputs} --objective "
        f"{objective}`: {_OBJECTIVE_WORDS[objective]} validation N-MSE {cost:.5f} at "
        f"{budget} epochs.\n# Dotted overrides; use with `include:` in an experiment rule, "
        "or --set each line.\n"
    )
    tuned_path = write_yaml(search.out / "tuned.yaml", header, best_values)
    # The caller prints result.format() (the CLI does).
    return search.result(facade, best_values, (cost, budget), [config_path, tuned_path])


def balance_budget(
    epochs: int | None = None, trials: int | None = None, paper_budget: bool = False
) -> tuple[int, int]:
    """``tune_balance``'s (epochs per model and trial, trials): the given values, else the
    CPU-sized defaults, or with ``paper_budget`` the paper's; a value below 1 is an error."""
    if epochs is None:
        epochs = PAPER_BALANCE_EPOCHS if paper_budget else BALANCE_EPOCHS
    if trials is None:
        trials = PAPER_BALANCE_TRIALS if paper_budget else BALANCE_TRIALS
    if epochs < 1 or trials < 1:
        raise ConfigError(f"epochs and trials must be >= 1, got {epochs}, {trials}")
    return epochs, trials


def tune_balance(
    config: str | Path = "table2",
    *,
    quick: bool = False,
    models: Sequence[str] | None = None,
    inputs: str = "ALL",
    condition: str | None = "seen",
    epochs: int | None = None,
    trials: int | None = None,
    paper_budget: bool = False,
    objective: str = DEFAULT_OBJECTIVE,
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

    Cost of a value: the mean over ``models`` (default: every registered model) of the
    validation N-MSE of the ``objective`` epoch after ``epochs`` epochs of balanced
    training. ``epochs`` x ``trials`` default to 10 x 30, or the paper's 50 x 132 with
    ``paper_budget`` (:func:`balance_budget`). Writes ``OUT/tuned.yaml``,
    ``OUT/best-MODEL.yaml`` per model and, when ``config`` is an experiment NAME,
    ``OUT/NAME-tuned.yaml``. See docs/experiments.md, "tune-balance".
    """
    smac = require_smac()
    from ConfigSpace import ConfigurationSpace, Integer

    epochs, trials = balance_budget(epochs, trials, paper_budget)
    check_objective(objective)
    inputs = canonical_inputs(inputs)
    models = [m.strip().lower() for m in (list_models() if models is None else models)]
    label = "balance" + ("-quick" if quick else "")
    search = _Search.of(label, f"tune-balance {', '.join(models)}", locals())
    bases = search.bases(models, inputs)
    base_dicts = search.trial_bases(bases)
    configspace = ConfigurationSpace(seed=seed)
    configspace.add(Integer("t_balance_percent", (0, 100), default=50))
    name = search_name("smac", base_dicts, epochs, seed, "balance", objective)
    scenario = search.scenario(smac, configspace, name, n_trials=trials)
    facade, incumbent = search.run(
        smac.HyperparameterOptimizationFacade,
        scenario,
        bases,
        lambda threads: BalanceObjective(
            base_dicts, str(search.out / "trials"), epochs, threads, objective=objective
        ),
        f"tune-balance{' (quick)' if quick else ''}",
    )
    cost, _ = incumbent_cost(facade, incumbent)
    t_balance = int(plain(incumbent["t_balance_percent"])) / 100
    best = {"sampling.strategy": "balanced", "sampling.t_balance": t_balance}
    header = (
        f"# Tuned by `tactile-compliance tune-balance --objective {objective}`: mean "
        f"{_OBJECTIVE_WORDS[objective]} validation N-MSE {cost:.5f} of {', '.join(models)} "
        f"after {epochs} epochs, {trials} trials.\n"
    )
    tuned_path = write_yaml(search.out / "tuned.yaml", header, best)
    tuned = [
        *(f"{key}={value}" for key, value in best.items()),
        f"output_dir={Path('runs') / label}",
    ]
    tuned_cfgs = [config_from_dict(config_to_dict(base), tuned) for base in bases]
    extra_paths = [save_config(c, search.out / f"best-{c.model.name}.yaml") for c in tuned_cfgs]
    config_path = extra_paths[0]
    spec = load_experiment(config, quick=False)
    if not spec.is_plain_config:
        ref = str(config) if spec.origin.startswith("experiment preset") else spec.origin
        experiment = {
            "description": f"{spec.description} (t_balance tuned: {t_balance})",
            "extends": ref,
            "set": best,
        }
        # Named after the experiment: its runs go to runs/NAME-tuned(-quick).
        config_path = write_yaml(search.out / f"{spec.name}-tuned.yaml", header, experiment)
    others = [p for p in extra_paths if p != config_path]
    return search.result(
        facade,
        {"sampling.t_balance": t_balance},
        (cost, None),
        [config_path, tuned_path, *others],
        decode=False,
    )
