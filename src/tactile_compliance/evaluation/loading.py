"""Reading what the report is built from: the results store and the files its runs left.

A run file that is missing or unreadable comes back as ``None``: a run directory moved
since the grid ran must cost one panel, not the report.
"""

from __future__ import annotations

import math
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from tactile_compliance.data.store import (
    GraspStore,
    StoreError,
    StoreHeader,
    read_samples_table,
    read_store_header,
)
from tactile_compliance.runs.results import (
    ROWS_DIR,
    STATUS_COMPLETE,
    ResultsStore,
    row_grouping,
    split_protocol,
)

__all__ = [
    "complete_rows",
    "load_results",
    "main_grid",
    "read_epoch_metrics",
    "read_groups",
    "read_label_span",
    "read_store_samples",
    "read_test_predictions",
    "resolve_run_dir",
    "store_header",
    "subset_rows",
]

#: Shore-hardness data (Table III): by the store header's source, or by the preset name
#: when the store is not reachable from where the report is built.
SHORE_SOURCES = frozenset({"yuan"})
SHORE_PRESETS = frozenset({"new-dataset"})


def _blank(value: Any) -> bool:
    """A results cell with nothing in it: None, NaN (pandas' missing value) or ``""``."""
    return value is None or (isinstance(value, float) and math.isnan(value)) or str(value) == ""


# ============================================================================ stores
@lru_cache(maxsize=64)
def _header_cached(path: str) -> StoreHeader | None:
    try:
        return read_store_header(path)
    except (StoreError, OSError):
        return None


def store_header(path: Any) -> StoreHeader | None:
    """A store's header, or None when the store is not reachable here."""
    if _blank(path):
        return None
    return _header_cached(str(Path(str(path)).expanduser().resolve()))


def read_store_samples(store: str) -> tuple[pd.DataFrame, str] | None:
    """A store's samples table and its header's source; None when it is not reachable."""
    try:
        opened = GraspStore.open(store)
        return opened.samples, opened.header.source
    except (StoreError, OSError, ValueError):
        # Fig. 1 needs only the table: a store copied without its frames still plots.
        header = store_header(store)
        if header is None:
            return None
        try:
            return read_samples_table(store), header.source
        except StoreError:
            return None


# ============================================================================ results store
def _subset_kind(value: Any) -> tuple[str, Any]:
    """Classify a row's ``subset``: ``none`` | ``window`` (0-6) | ``softhard`` | ``shape``."""
    if _blank(value):
        return "none", None
    if isinstance(value, (bool, np.bool_)):
        return "shape", str(value)
    if isinstance(value, (int, np.integer)) or (
        isinstance(value, (float, np.floating)) and float(value).is_integer()
    ):
        return "window", int(value)
    text = str(value).strip()
    if text.lower() in ("", "none", "null"):
        return "none", None
    if text.isdigit():
        return "window", int(text)
    if text.lower() in ("soft", "hard"):
        return "softhard", text.lower()
    return "shape", text


def _protocol(condition: Any, grouping: Any) -> str | None:
    """The row's object condition; None when its condition is not recorded."""
    try:
        return split_protocol(condition, grouping)
    except ValueError:
        return None


def load_results(results_dir: str | Path) -> pd.DataFrame:
    """All rows of the results store plus the columns the report selects on.

    Added: ``subset_kind`` / ``subset_value`` (:func:`_subset_kind`), ``protocol`` (the
    object condition, one of ``runs.results.PROTOCOLS``), ``store_source`` (None when the
    store is not reachable) and ``is_shore`` (Table III data); ``grouping`` is filled in
    for rows written before it was recorded.

    Raises:
        FileNotFoundError: ``results_dir`` does not exist (a typo must not look like an
            empty store).
    """
    path = Path(results_dir)
    if not path.is_dir():
        raise FileNotFoundError(f"{path}: no such results directory")
    if not (path / ROWS_DIR).is_dir():
        frame = pd.DataFrame(columns=["key", "preset", "status", "store"])
    else:
        frame = ResultsStore(path).table()
    needed = ("preset", "store", "status", "model", "inputs", "condition", "grouping")
    for column in (*needed, "sampling", "seed", "subset", "run_dir", "error"):
        if column not in frame.columns:
            frame[column] = None
    frame["preset"] = frame["preset"].fillna("").astype(str)
    pairs = list(zip(frame["condition"], frame["grouping"], strict=True))
    frame["grouping"] = [row_grouping(c, g) for c, g in pairs]
    frame["protocol"] = [_protocol(c, g) for c, g in pairs]
    kinds = [_subset_kind(v) for v in frame["subset"].tolist()]
    frame["subset_kind"] = [k for k, _ in kinds]
    frame["subset_value"] = pd.Series([v for _, v in kinds], index=frame.index, dtype=object)
    frame["store_source"] = [getattr(store_header(s), "source", None) for s in frame["store"]]
    frame["is_shore"] = [
        (src in SHORE_SOURCES) or any(preset.startswith(p) for p in SHORE_PRESETS)
        for src, preset in zip(frame["store_source"], frame["preset"], strict=True)
    ]
    return frame


def complete_rows(frame: pd.DataFrame) -> pd.DataFrame:
    """Rows whose run finished (the only ones any table or figure uses)."""
    return frame[frame["status"] == STATUS_COMPLETE]


def subset_rows(frame: pd.DataFrame, kind: str, shore: bool = False) -> pd.DataFrame:
    """Complete rows of one ``subset_kind`` (``none``: the whole dataset), on Shore-hardness
    data (``shore``) or not."""
    done = complete_rows(frame)
    return done[(done["subset_kind"] == kind) & (done["is_shore"].astype(bool) == shore)]


def main_grid(frame: pd.DataFrame) -> pd.DataFrame:
    """Complete rows of the main grid: whole dataset (no subset), not Shore data."""
    return subset_rows(frame, "none")


# ============================================================================ run directories
def resolve_run_dir(value: Any, results_dir: str | Path) -> Path | None:
    """Find a run directory recorded as ``value`` (absolute, or relative to where the grid
    ran, which need not be here: docs/reporting.md, "Which rows feed which part")."""
    if _blank(value):
        return None
    path = Path(str(value)).expanduser()
    root = Path(results_dir)
    candidates = [path] if path.is_absolute() else [path, root / path, root.parent / path]
    candidates += [root / path.name, root / "runs" / path.name]
    for candidate in candidates:
        if candidate.is_dir():
            return candidate
    return None


def read_test_predictions(run_dir: Path | None) -> pd.DataFrame | None:
    """The test-split rows of a run's ``predictions.csv`` with positive moduli, or None.

    A file without the modulus columns raises ``KeyError``: a broken run gets a note.
    """
    if run_dir is None or not (run_dir / "predictions.csv").is_file():
        return None
    predictions = pd.read_csv(run_dir / "predictions.csv")
    if "split" in predictions.columns:
        predictions = predictions[predictions["split"] == "test"]
    predictions = predictions[(predictions["modulus_pa"] > 0) & (predictions["pred_pa"] > 0)]
    return predictions if not predictions.empty else None


def read_label_span(run_dir: Path | None) -> float | None:
    """Label span in decades (9 on [1e3, 1e12]) from a run's ``config.yaml``; None if unknown."""
    if run_dir is not None and (run_dir / "config.yaml").is_file():
        try:
            import yaml

            config = yaml.safe_load((run_dir / "config.yaml").read_text()) or {}
            lo, hi = config.get("data", {}).get("label_range_pa")
            return math.log10(float(hi)) - math.log10(float(lo))
        except Exception:
            # Any malformed config (no data section, no range, text in it) means "unknown":
            # the caller falls back to the data's default range.
            pass
    return None


def read_groups(run_dir: Path | None) -> pd.DataFrame | None:
    """A run's ``groups.csv`` (per-material / shape / stiffness metrics), or None."""
    if run_dir is None:
        return None
    path = run_dir / "groups.csv"
    try:
        return pd.read_csv(path, dtype={"group": str})
    except (OSError, ValueError):
        return None


def read_epoch_metrics(run_dir: Path | None) -> pd.DataFrame | None:
    """One row per epoch of a run's ``logs/metrics.csv`` (``train_loss``, ``val_nmse``), or None."""
    path = None if run_dir is None else run_dir / "logs" / "metrics.csv"
    if path is None or not path.is_file():
        return None
    try:
        log_frame = pd.read_csv(path)
    except (OSError, ValueError):
        return None
    if "epoch" not in log_frame.columns:
        return None
    cols = [c for c in ("train_loss", "val_nmse") if c in log_frame.columns]
    if not cols:
        return None
    # Lightning writes train and validation values on separate lines of one epoch.
    return log_frame.groupby("epoch")[cols].first().reset_index()
