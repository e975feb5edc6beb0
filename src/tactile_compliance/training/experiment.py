"""Experiment grids on Dask: expand a grid, run every cell through ``train``, record it.

See docs/experiments.md, "Running a grid" (layout, resuming, failures, Dask).
"""

from __future__ import annotations

import contextlib
import functools
import json
import os
import socket
import sys
import time
import traceback
import warnings
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, TypedDict

import pandas as pd
from typing_extensions import Unpack  # typing.Unpack needs Python 3.11

from tactile_compliance.config import (
    ConfigError,
    config_from_dict,
    config_to_dict,
)
from tactile_compliance.outputs import (
    DirectoryLockedError,
    atomic_file,
    claim_output_dir,
    exclusive_lock,
)
from tactile_compliance.progress import progress_bar
from tactile_compliance.runs.layout import (
    LOCK_FILE,
    RUN_KIND,
    check_keep_checkpoints,
    prune_checkpoints,
)
from tactile_compliance.runs.results import (
    STATUS_COMPLETE,
    STATUS_FAILED,
    ResultsStore,
    result_row,
    row_grouping,
)
from tactile_compliance.training.cluster import dask_client, limit_threads
from tactile_compliance.training.experiment_file import (
    Cell,
    ExperimentSpec,
    expand_experiment,
    experiment_preset_descriptions,
    list_experiment_presets,
    load_experiment,
)

__all__ = [
    "ExperimentError",
    "ExperimentPlan",
    "ExperimentSummary",
    "aggregate_results",
    "experiment_preset_descriptions",
    "list_experiment_presets",
    "plan_experiment",
    "precompute_features",
    "run_cell",
    "run_experiment",
]

RESULTS_DIR = "results"
ATTEMPTS_FILE = "attempts.json"
EXPERIMENT_FILE = "experiment.json"
#: Metrics shown in the summary (mean +- std over seeds).
SUMMARY_METRICS = ("test_log10_accuracy", "test_nmse")


class ExperimentError(RuntimeError):
    """The experiment cannot run (missing store, locked results store, ...)."""


# =========================================================================== worker side
@functools.cache  # once per worker process, not once per cell
def _quiet_training_warnings() -> None:
    # Every cell would repeat Lightning's start-up banner and its advice about loader
    # workers and logging intervals; it says nothing about the results, so keep worker
    # logs readable (errors and real warnings still show).
    import logging

    from tactile_compliance.training.train import LIGHTNING_LOGGERS, quiet_lightning_warnings

    for name in LIGHTNING_LOGGERS:
        logging.getLogger(name).setLevel(logging.WARNING)
    quiet_lightning_warnings()
    warnings.filterwarnings("ignore", message=".*cached image features.*")


def precompute_features(cfg_dicts: Sequence[dict[str, Any]], threads: int | None = None) -> int:
    """Compute (or find) the frozen-backbone feature cache of each config; return their count.

    One Dask task per model, run before the cells that need the caches. Configs whose
    caches are the same (same store and ``data.features.cache_key``: backbone, weights,
    frame size, image normalisation) are computed once; the count is of distinct caches.
    """
    from tactile_compliance.data.features import cache_key
    from tactile_compliance.data.store import GraspStore
    from tactile_compliance.runs.run_inputs import RunInputs
    from tactile_compliance.training.train import build_model, frozen_features

    limit_threads(threads)
    _quiet_training_warnings()
    done: set[tuple[str, str]] = set()
    for data in cfg_dicts:
        cfg = config_from_dict(data)
        model = build_model(cfg)
        store = GraspStore.open(cfg.data.store)
        run_inputs = RunInputs.resolve(cfg, store, model)  # what train() resolves
        identity = (
            str(store.path.resolve()),
            cache_key(
                model.backbone,
                run_inputs.image_size,
                run_inputs.constants,
                run_inputs.inputs.image.name,
            ),
        )
        if identity not in done:
            frozen_features(cfg, store, model, run_inputs, progress=False)
            done.add(identity)
    return len(done)


def _count_attempt(run_dir: Path) -> int:
    """Record one more start of this cell in ``RUN_DIR/attempts.json``; return the count."""
    path = run_dir / ATTEMPTS_FILE
    history: list[dict[str, Any]] = []
    if path.exists():
        with contextlib.suppress(ValueError, OSError):
            history = list(json.loads(path.read_text()).get("history", []))
    history.append(
        {
            "started": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "host": socket.gethostname(),
            "pid": os.getpid(),
        }
    )
    claim_output_dir(run_dir, RUN_KIND)
    with atomic_file(path, unique=True) as handle:
        handle.write(json.dumps({"attempts": len(history), "history": history}, indent=2) + "\n")
    return len(history)


def _attempts(run_dir: Path) -> int:
    try:
        return int(json.loads((run_dir / ATTEMPTS_FILE).read_text())["attempts"])
    except (OSError, ValueError, KeyError):
        return 1


def run_cell(
    cfg_dict: dict[str, Any],
    key: str,
    preset: str,
    results_path: str,
    threads: int | None = None,
    after: Any = None,
    keep_checkpoints: str = "best",
) -> dict[str, Any]:
    """Dask task: train one cell and record its row (``complete`` or ``failed``).

    Never raises for a failing run: the error and traceback go into the row. ``after`` is
    only a dependency (the feature-cache task), so Dask starts the cell once it is done.
    ``keep_checkpoints`` as for :func:`run_experiment`.
    """
    del after
    from tactile_compliance.runs.layout import run_name
    from tactile_compliance.training.train import train

    limit_threads(threads)
    _quiet_training_warnings()
    results = ResultsStore(results_path)
    if results.is_complete(key):  # a retried task whose first attempt got that far
        row = results.get(key)
        assert row is not None
        return row
    cfg = config_from_dict(cfg_dict)
    run_dir = Path(cfg.output_dir) / run_name(cfg)
    attempts = _count_attempt(run_dir)
    started = time.perf_counter()
    extra: dict[str, Any] = {"host": socket.gethostname()}
    result, error = None, None
    try:
        # train() resumes from the last finished epoch, or sets a damaged checkpoint aside.
        result = train(cfg, run_dir=run_dir, progress=False)
        prune_checkpoints(run_dir, keep_checkpoints)
    except Exception as exc:  # recorded, never lost: the grid goes on
        result, error = None, f"{type(exc).__name__}: {exc}"
        extra["traceback"] = traceback.format_exc()
    wall_time_s = round(time.perf_counter() - started, 2)
    row = result_row(
        cfg, result, preset=preset, error=error, attempts=attempts, wall_time_s=wall_time_s
    )
    row.update(extra)
    row["run_dir"] = row.get("run_dir") or str(run_dir)
    results.record(row)
    return row


# =========================================================================== driver side
@dataclass
class ExperimentPlan:
    """What an experiment would run: the spec, its cells and where results go."""

    spec: ExperimentSpec
    cells: list[Cell]
    output_dir: Path
    results_path: Path

    @property
    def preset(self) -> str:
        """The name recorded in each row's ``preset`` column."""
        return f"{self.spec.name}-quick" if self.spec.quick else self.spec.name

    def status(self) -> dict[str, str]:
        """``{key: complete | failed | todo}`` from the results store."""
        store = ResultsStore(self.results_path)
        return {cell.key: (store.get(cell.key) or {}).get("status", "todo") for cell in self.cells}

    def format(self) -> str:
        """One line per cell with its status (for ``--dry-run``)."""
        status = self.status()
        lines = [
            f"{self.preset}: {self.spec.description}",
            f"{len(self.cells)} cells, output {self.output_dir}, results {self.results_path}",
            *(f"  {status[cell.key]:<9} {cell.key}  {cell.label}" for cell in self.cells),
        ]
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        """What :meth:`format` shows, for ``--dry-run --json``."""
        status = self.status()
        return {
            "preset": self.preset,
            "description": self.spec.description,
            "output_dir": str(self.output_dir),
            "results": str(self.results_path),
            "cells": [
                {"key": cell.key, "label": cell.label, "status": status[cell.key]}
                for cell in self.cells
            ],
        }


class PlanOptions(TypedDict, total=False):
    """Which cells of an experiment run and where they go (``run_experiment``'s Args)."""

    quick: bool
    seeds: Sequence[int] | int | None
    store: str | Path | None
    overrides: Iterable[str]
    where: Iterable[str]
    output_dir: str | Path | None
    results: str | Path | None


def plan_experiment(preset_or_path: str | Path, **options: Unpack[PlanOptions]) -> ExperimentPlan:
    """Load and expand an experiment without running anything (see :func:`run_experiment`)."""
    spec = load_experiment(preset_or_path, quick=options.get("quick", False))
    output_dir, results = options.get("output_dir"), options.get("results")
    out = Path(output_dir) if output_dir is not None else spec.default_output_dir
    cells = expand_experiment(
        spec,
        seeds=options.get("seeds"),
        store=options.get("store"),
        overrides=options.get("overrides", ()),
        where=options.get("where", ()),
        output_dir=out,
    )
    out = out.expanduser().resolve()
    results_path = Path(results).expanduser() if results is not None else out.parent / RESULTS_DIR
    return ExperimentPlan(spec, cells, out, results_path.resolve())


@dataclass
class ExperimentSummary:
    """What one ``run_experiment`` call did, and where to find the results."""

    name: str
    output_dir: Path
    results_path: Path
    cells: int
    skipped: int = 0
    completed: int = 0
    failed: int = 0
    wall_time_s: float = 0.0
    workers: int | str = 1
    interrupted: bool = False
    failures: list[tuple[str, str]] = field(default_factory=list)
    keys: list[str] = field(default_factory=list)

    def table(self) -> pd.DataFrame:
        """The rows of this experiment's cells (one per cell that has a row)."""
        table = ResultsStore(self.results_path).table()
        if table.empty:
            return table
        return table[table["key"].isin(self.keys)].reset_index(drop=True)

    def format(self) -> str:
        """A printable summary: counts, failures and mean +- std of the main metrics."""
        lines = [
            f"Experiment {self.name}: {self.cells} cells: {self.skipped} already complete, "
            f"{self.completed} completed now, {self.failed} failed"
            + (" (interrupted: re-run the same command to continue)" if self.interrupted else "")
            + f"; {self.wall_time_s:.1f} s on {self.workers} worker(s)",
            f"Runs in {self.output_dir}; results in {self.results_path}",
        ]
        for label, error in self.failures[:20]:
            first = error.strip().splitlines()[0] if error.strip() else "?"
            lines.append(f"  FAILED {label}: {first}")
        if len(self.failures) > 20:
            lines.append(f"  ... and {len(self.failures) - 20} more failures")
        summary = aggregate_results(self.table())
        if not summary.empty:
            with pd.option_context("display.width", 200, "display.max_rows", 200):
                lines.append(summary.to_string(index=False))
        return "\n".join(lines)

    def to_dict(self) -> dict[str, Any]:
        """What :meth:`format` shows, for ``--json``: the counts, every failure with its
        error, and the mean +- std rows (``aggregate_results``; a missing value is None)."""
        summary = aggregate_results(self.table())
        return {
            "name": self.name,
            "output_dir": str(self.output_dir),
            "results": str(self.results_path),
            "cells": self.cells,
            "skipped": self.skipped,
            "completed": self.completed,
            "failed": self.failed,
            "interrupted": self.interrupted,
            "wall_time_s": round(self.wall_time_s, 2),
            "workers": self.workers,
            "failures": [{"cell": label, "error": error} for label, error in self.failures],
            "summary": summary.astype(object).where(summary.notna(), None).to_dict("records"),
        }


def aggregate_results(table: pd.DataFrame) -> pd.DataFrame:
    """Mean +- std over seeds of the test metrics of complete rows, one row per configuration."""
    if table.empty or "status" not in table.columns:
        return pd.DataFrame()
    done = table[table["status"] == STATUS_COMPLETE]
    metrics = [m for m in SUMMARY_METRICS if m in done.columns]
    if done.empty or not metrics:
        return pd.DataFrame()
    frame = done
    if "condition" in frame.columns:
        # The object condition is (condition, grouping): per-sample and grasp-grouped seen
        # runs must not be pooled; rows written before grouping was recorded are grasp.
        old = frame["grouping"] if "grouping" in frame.columns else [None] * len(frame)
        frame = frame.assign(
            grouping=[row_grouping(c, g) for c, g in zip(frame["condition"], old, strict=True)]
        )
    by = [
        c
        for c in ("model", "inputs", "condition", "grouping", "sampling", "subset")
        if c in frame.columns
    ]
    if "subset" in by:  # None (whole store) would otherwise drop out of the groups
        frame = frame.assign(subset=[("-" if pd.isna(v) else str(v)) for v in frame["subset"]])
    grouped = frame.groupby(by, dropna=False, sort=True)
    out = grouped.size().rename("seeds").reset_index()
    for metric in metrics:
        stats = grouped[metric].agg(["mean", "std"]).reset_index(drop=True)
        short = metric.removeprefix("test_")
        out[short] = [
            f"{m:.4f} +- {s:.4f}" if pd.notna(s) else f"{m:.4f}"
            for m, s in zip(stats["mean"], stats["std"], strict=True)
        ]
    return out


@contextlib.contextmanager
def _locked(output_dir: Path) -> Iterator[None]:
    """Hold an exclusive lock on an experiment's output directory for one driver's lifetime."""
    output_dir.mkdir(parents=True, exist_ok=True)
    try:
        what = "experiment output directory (--out)"
        with exclusive_lock(output_dir / LOCK_FILE, what, wait=False):
            yield
    except DirectoryLockedError as err:
        raise ExperimentError(str(err)) from None


def _check_stores(cells: Sequence[Cell]) -> None:
    stores = {c.cfg.data.store or "" for c in cells}
    missing = sorted(store for store in stores if not (store and Path(store).is_dir()))
    if missing:
        shown = ", ".join(m or "(data.store not set)" for m in missing)
        raise ExperimentError(
            f"store not found: {shown}. Create one (tactile-compliance import ... --out PATH, "
            "see docs/data.md) and pass it with --store PATH"
        )


def _write_plan(plan: ExperimentPlan) -> None:
    plan.output_dir.mkdir(parents=True, exist_ok=True)
    data = {
        **plan.spec.to_dict(),
        "preset": plan.preset,
        "results": str(plan.results_path),
        "cells": [
            {"key": c.key, "label": c.label, "axes": c.axes, "run_dir": str(c.run_dir)}
            for c in plan.cells
        ],
    }
    path = plan.output_dir / EXPERIMENT_FILE
    with atomic_file(path) as handle:
        handle.write(json.dumps(data, indent=2, default=str) + "\n")


def run_experiment(
    preset_or_path: str | Path,
    *,
    workers: int = 1,
    scheduler: str | None = None,
    client: Any = None,
    retry_failed: bool = True,
    threads: int | None = None,
    keep_checkpoints: str = "best",
    progress: bool = True,
    **plan_options: Unpack[PlanOptions],
) -> ExperimentSummary:
    """Run every cell of an experiment grid on Dask and record it in the results store.

    Idempotent: a cell is its config hash, so re-running the same command skips complete
    cells, retries failed ones and resumes interrupted ones (``train`` does), and no cell
    runs twice to completion. An exception in a cell is recorded as a ``failed`` row and
    the grid goes on. One driver at a time per output directory (a lock).

    Args:
        preset_or_path: experiment preset (``list_experiment_presets()``), experiment YAML,
            or a plain config (preset or file, e.g. ``tune``'s ``best.yaml``: one cell).
        plan_options (:class:`PlanOptions`, handed to :func:`plan_experiment`):
        quick: use the experiment's ``quick`` variant (small, for a 2-core CPU).
        seeds: seed count (0..n-1) or list; default: the experiment's.
        store: GraspStore for every cell (default: the experiment's ``data.store``).
        overrides: ``dotted.key=value`` for every cell (applied last).
        where: ``key=value`` filters: run only the matching cells.
        workers: local Dask worker processes (ignored with ``scheduler``/``client``).
        scheduler: address or scheduler-file of a running Dask scheduler.
        client: an existing ``distributed.Client`` (Python API).
        output_dir: run directories (default ``runs/NAME`` / ``runs/NAME-quick``).
        results: results store directory (default ``OUTPUT/../results``, i.e.
            ``runs/results``: one store for all experiments, as ``report`` expects).
        retry_failed: re-run cells recorded as failed (else skip them like complete ones).
        threads: torch threads per cell (default 1: one single-threaded cell per worker;
            several threads per cell are slower than several workers on a busy CPU).
        keep_checkpoints: what a finished run keeps: ``best`` (``best.pt``, default),
            ``all`` (also ``checkpoints/last.ckpt``) or ``none`` (metrics, predictions and
            logs only).
        progress: show a progress bar of cells done / failed.

    Returns:
        An :class:`ExperimentSummary` (``.format()`` is the printable summary, ``.table()``
        the rows). Only an interrupted run prints its summary itself (to stderr).

    Raises:
        ConfigError: the experiment or one of its cells is invalid (nothing has run).
        ExperimentError: a store is missing, or another driver holds the results store.
        KeyboardInterrupt: after cancelling the pending cells (finished rows are kept).
    """
    check_keep_checkpoints(keep_checkpoints)
    started = time.perf_counter()
    plan = plan_experiment(preset_or_path, **plan_options)
    if not plan.cells:
        raise ConfigError(f"{plan.preset}: no cells to run (check the filters)")
    remote = scheduler is not None or client is not None
    summary = ExperimentSummary(
        name=plan.preset,
        output_dir=plan.output_dir,
        results_path=plan.results_path,
        cells=len(plan.cells),
        workers=scheduler or ("client" if client is not None else workers),
        keys=[c.key for c in plan.cells],
    )
    if not remote and not Path(plan.results_path).exists():
        # A fresh experiment runs every cell: a missing store is reported before the
        # output folders are created, so the failed command leaves nothing behind.
        _check_stores(plan.cells)
    claim_output_dir(plan.output_dir, "experiment", option="--out")
    claim_output_dir(plan.results_path, "results", option="--results")
    with _locked(plan.output_dir):
        skip = {STATUS_COMPLETE} if retry_failed else {STATUS_COMPLETE, STATUS_FAILED}
        status = plan.status()
        todo = [cell for cell in plan.cells if status[cell.key] not in skip]
        summary.skipped = len(plan.cells) - len(todo)
        if not remote:
            _check_stores(todo)
        _write_plan(plan)
        if todo:
            try:
                with dask_client(workers, scheduler, client) as dask:
                    threads = 1 if threads is None else threads
                    _dispatch(dask, plan, todo, summary, threads, keep_checkpoints, progress)
            except KeyboardInterrupt:
                summary.interrupted = True
                summary.wall_time_s = round(time.perf_counter() - started, 2)
                if progress:
                    print(summary.format(), file=sys.stderr)
                raise
    summary.wall_time_s = round(time.perf_counter() - started, 2)
    return summary  # the caller prints summary.format() (the CLI does)


def _dispatch(
    dask: Any,
    plan: ExperimentPlan,
    todo: list[Cell],
    summary: ExperimentSummary,
    threads: int,
    keep_checkpoints: str,
    progress: bool,
) -> None:
    """Run the cells ``todo`` on the Dask client ``dask``, counting them in ``summary``."""
    from distributed import as_completed

    results_path = str(plan.results_path)
    store_rows = ResultsStore(plan.results_path)
    with progress_bar(
        plan.preset,
        len(todo),
        progress,
        fields={"done": 0, "failed": 0},
        fields_format="[green]{task.fields[done]} done[/] [red]{task.fields[failed]} failed",
    ) as bar:
        # One feature-cache task per model, before that model's frozen-backbone cells.
        # The worker tells which cells share a cache (data.features.cache_key), so the
        # driver only groups them by model.
        by_model: dict[str, list[dict[str, Any]]] = {}
        for cell in todo:
            if cell.cfg.model.freeze_backbone:
                by_model.setdefault(cell.cfg.model.name, []).append(config_to_dict(cell.cfg))
        caches = {
            model: dask.submit(precompute_features, cfgs, threads, pure=False)
            for model, cfgs in by_model.items()
        }
        futures: dict[Any, Cell] = {}
        for cell in todo:
            after = caches.get(cell.cfg.model.name) if cell.cfg.model.freeze_backbone else None
            future = dask.submit(
                run_cell,
                config_to_dict(cell.cfg),
                cell.key,
                plan.preset,
                results_path,
                threads,
                after,
                keep_checkpoints,
                pure=False,
            )
            futures[future] = cell
        try:
            for future in as_completed(list(futures)):
                cell = futures[future]
                try:
                    row = future.result()
                except Exception as exc:  # the worker died repeatedly, or its cache failed
                    row = _record_lost_cell(store_rows, cell, plan.preset, exc)
                if row.get("status") == STATUS_COMPLETE:
                    summary.completed += 1
                else:
                    summary.failed += 1
                    summary.failures.append((cell.label, str(row.get("error") or "")))
                bar.update(advance=1, done=summary.completed, failed=summary.failed)
        except KeyboardInterrupt:
            # Finished rows are on disk already; drop the rest so the cluster closes fast.
            for future in [*futures, *caches.values()]:
                future.cancel()
            raise


def _record_lost_cell(
    store_rows: ResultsStore, cell: Cell, preset: str, exc: BaseException
) -> dict[str, Any]:
    """Record a cell whose task never returned (worker killed too often, cache failure)."""
    existing = store_rows.get(cell.key)
    if existing is not None and existing.get("status") == STATUS_COMPLETE:
        return existing
    name = type(exc).__name__
    message = f"{name}: {exc}"
    if name == "KilledWorker":
        message += " (the worker process died while running this cell: out of memory?)"
    row = result_row(cell.cfg, None, preset=preset, error=message, attempts=_attempts(cell.run_dir))
    row["run_dir"] = str(cell.run_dir)
    row["traceback"] = "".join(traceback.format_exception(exc))
    store_rows.record(row)
    return row
