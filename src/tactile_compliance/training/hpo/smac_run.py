"""Running SMAC: start or continue a search, run its trials, read its run history.

SMAC continues an earlier run only when the saved scenario equals the new one and asks
on stdin otherwise; this module reconciles the saved state (trial budget, interrupted
trials) so that re-running a command resumes it, and turns the prompt into an error.
"""

from __future__ import annotations

import builtins
import contextlib
import hashlib
import json
import logging
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from tactile_compliance.outputs import atomic_file
from tactile_compliance.progress import ProgressBar, progress_bar
from tactile_compliance.training.cluster import dask_client
from tactile_compliance.training.hpo.space import plain, trial_values

__all__ = [
    "CRASH_COST",
    "TuneError",
    "incumbent_cost",
    "require_smac",
    "run_smac",
    "search_name",
    "trial_cluster",
    "trials_table",
]

#: Cost SMAC records for a trial that raised (validation N-MSE of labels in [0, 1] is <= 1).
CRASH_COST = 1.0


class TuneError(RuntimeError):
    """Tuning cannot start or continue (SMAC missing, an incompatible earlier run, ...)."""


def require_smac() -> Any:
    """The ``smac`` module, or a TuneError that says how to install it."""
    try:
        import smac
    except ImportError as exc:
        raise TuneError(
            "tuning needs SMAC3: pip install 'tactile-compliance[hpo]' (smac>=2.3,<3)"
        ) from exc
    return smac


def search_name(prefix: str, *parts: Any) -> str:
    """A SMAC run name hashing what defines the search (and SMAC's version)."""
    import smac

    blob = json.dumps([*parts, smac.version], sort_keys=True, default=str)
    return f"{prefix}-{hashlib.sha256(blob.encode()).hexdigest()[:10]}"


# =========================================================================== resuming
def _reconcile_previous_run(scenario: Any) -> None:
    """Let SMAC continue an earlier run that differs only in its trial budget: the
    directory name pins everything else, so write the new trial and time limits into the
    saved scenario (and un-finish it when more trials are asked for)."""
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
    with atomic_file(saved_path) as handle:
        handle.write(json.dumps(saved, indent=4))
    optimization = directory / "optimization.json"
    if optimization.exists():
        state = json.loads(optimization.read_text())
        state["finished"] = False
        with atomic_file(optimization) as handle:
            handle.write(json.dumps(state, indent=2))


def _forget_unfinished_trials(directory: Path) -> None:
    """Drop trials an interrupted SMAC run saved as RUNNING, so that they run again.

    SMAC saves a trial as RUNNING when it hands it out; a resumed SMAC would otherwise
    count it forever without a result.
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
    with atomic_file(path) as handle:
        handle.write(json.dumps(history, indent=2))


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


# =========================================================================== running
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


@contextlib.contextmanager
def trial_cluster(
    workers: int, scheduler: str | None, client: Any, threads: int | None
) -> Iterator[tuple[Any, int | None]]:
    """(Dask client or None for serial trials, torch threads per trial: 1 when parallel)."""
    if workers <= 1 and scheduler is None and client is None:
        yield None, threads
        return
    with dask_client(workers, scheduler, client) as dask:
        yield dask, 1 if threads is None else threads


def run_smac(
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
) -> tuple[Any, Any]:
    """Start or continue the search of ``scenario``: (the facade, its incumbent).

    A TuneError when no trial finished, or (without ``overwrite``) when an earlier run in
    the directory cannot be continued.
    """
    logging.getLogger("smac").setLevel(logging.ERROR)
    _reconcile_previous_run(scenario)
    kwargs: dict[str, Any] = {"intensifier": intensifier} if intensifier is not None else {}
    # SMAC sizes its random initial design from n_trials; pin it to the first run's size
    # so that a search extended with more trials is still the same search.
    kwargs["initial_design"] = facade_cls.get_initial_design(
        scenario, n_configs=_initial_design_size(scenario), max_ratio=1.0
    )
    kwargs["acquisition_maximizer"] = _hash_independent_maximizer(facade_cls, scenario)
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


def _hash_independent_maximizer(facade_cls: Any, scenario: Any) -> Any:
    """The facade's acquisition maximizer, made independent of Python's string hashing.

    SMAC 2.4's local search lists its start points from a ``set``; sorting them by their
    vector makes the search reproducible. See docs/experiments.md, "Reproducibility".
    """
    maximizer = facade_cls.get_acquisition_maximizer(scenario)
    local_search = getattr(maximizer, "_local_search", None)
    collect = getattr(local_search, "_get_init_points_from_previous_configs", None)
    if collect is None:  # another SMAC version: nothing to fix (or it changed)
        return maximizer

    def ordered(*args: Any, **kwargs: Any) -> list[Any]:
        points = collect(*args, **kwargs)
        return sorted(points, key=lambda c: tuple(np.nan_to_num(c.get_array(), nan=-1.0)))

    local_search._get_init_points_from_previous_configs = ordered
    return maximizer


# =========================================================================== results
def trials_table(facade: Any, decode: bool = True) -> pd.DataFrame:
    """Every trial of the run history: configuration id, budget, cost, status, time and
    the values (decoded into config values unless ``decode`` is False)."""
    runhistory = facade.runhistory
    rows = []
    for key, value in runhistory.items():
        config = runhistory.get_config(key.config_id)
        values = trial_values(config) if decode else {k: plain(v) for k, v in dict(config).items()}
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


def incumbent_cost(facade: Any, incumbent: Any) -> tuple[float, float | None]:
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
