"""The results store: one row per run of a grid, kept as one JSON file per run.

See docs/experiments.md, "What lands where", for the layout and the row's columns.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import pandas as pd

from tactile_compliance.config import ExperimentConfig
from tactile_compliance.outputs import atomic_file
from tactile_compliance.runs.layout import config_hash, run_name

ROWS_DIR = "rows"
STATUS_COMPLETE = "complete"
STATUS_FAILED = "failed"
AXES = ("model", "inputs", "condition", "grouping", "sampling", "seed", "subset", "t_balance")

#: The three object conditions of Tables I and II, in table order: seen objects with the
#: paper's per-sample split (a grasp's near-duplicate samples straddle train and test),
#: seen objects with whole grasps kept in one split (leak-free), unseen objects.
PROTOCOLS: tuple[str, ...] = ("seen_per_sample", "seen_grasp", "unseen")
#: How tables, figures and summaries name each protocol (every header says which split).
PROTOCOL_LABELS: dict[str, str] = {
    "seen_per_sample": "Seen, per-sample (paper)",
    "seen_grasp": "Seen, grasp-grouped",
    "unseen": "UnSeen",
}


def row_grouping(condition: Any, grouping: Any) -> str:
    """A row's ``grouping``: ``object`` under unseen, else ``grasp`` (also when missing)."""
    if str(condition) == "unseen":
        return "object"
    return "per_sample" if str(grouping) == "per_sample" else "grasp"


def split_protocol(condition: Any, grouping: Any = None) -> str:
    """One of :data:`PROTOCOLS` for a run's ``split.condition`` and ``split.grouping``; a
    ValueError for a condition other than seen/unseen."""
    if str(condition) == "unseen":
        return "unseen"
    if str(condition) != "seen":
        raise ValueError(f"split condition must be 'seen' or 'unseen', got {condition!r}")
    return f"seen_{row_grouping(condition, grouping)}"


def _axes(cfg: ExperimentConfig) -> dict[str, Any]:
    return {
        "model": cfg.model.name,
        "inputs": cfg.inputs,
        "condition": cfg.split.condition,
        "grouping": row_grouping(cfg.split.condition, cfg.split.grouping),
        "sampling": cfg.sampling.strategy,
        "seed": cfg.seed,
        "subset": cfg.split.subset,
        "t_balance": cfg.sampling.t_balance if cfg.sampling.strategy == "balanced" else None,
    }


def _flatten(prefix: str, metrics: Mapping[str, Any]) -> dict[str, Any]:
    return {f"{prefix}_{name}": value for name, value in metrics.items()}


def result_row(
    cfg: ExperimentConfig,
    result: Mapping[str, Any] | None = None,
    *,
    preset: str = "",
    error: str | None = None,
    attempts: int = 1,
    wall_time_s: float | None = None,
) -> dict[str, Any]:
    """A results-store row for a finished (``result`` from ``train``) or failed run."""
    row: dict[str, Any] = {
        "key": config_hash(cfg),  # covers model, inputs, seed, data, ...
        "run_name": run_name(cfg),
        "preset": preset,
        "store": cfg.data.store,
        **_axes(cfg),
        "status": STATUS_FAILED if error is not None else STATUS_COMPLETE,
        "error": error,
        "attempts": attempts,
        "finished": datetime.now(timezone.utc).isoformat(timespec="seconds"),
    }
    if result is not None:
        row.update(
            {
                "run_dir": result.get("run_dir"),
                "wall_time_s": result.get("wall_time_s", wall_time_s),
                **_flatten("test", result.get("test", {})),
                **_flatten("val", result.get("val", {})),
                **{
                    key: result.get(key)
                    for key in (
                        "best_epoch",
                        "best_val_nmse",
                        "epochs_trained",
                        "n_train",
                        "n_val",
                        "n_test",
                        "backbone_weights",
                        "backbone_weights_sha256",
                        "freeze_backbone",
                        "image_size",
                    )
                },
            }
        )
        for name, metrics in result.get("reference", {}).items():
            row.update(_flatten(f"ref_{name}", metrics))
    else:
        row["wall_time_s"] = wall_time_s
    return row


class ResultsStore:
    """A directory of per-run JSON rows (safe for concurrent writers)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        (self.path / ROWS_DIR).mkdir(parents=True, exist_ok=True)

    def _row_path(self, key: str) -> Path:
        return self.path / ROWS_DIR / f"{key}.json"

    def get(self, key: str) -> dict[str, Any] | None:
        """The stored row of ``key``, or None."""
        path = self._row_path(key)
        if not path.exists():
            return None
        return json.loads(path.read_text())

    def is_complete(self, key: str) -> bool:
        row = self.get(key)
        return row is not None and row.get("status") == STATUS_COMPLETE

    def record(self, row: Mapping[str, Any]) -> Path:
        """Write (or replace) one row atomically."""
        path = self._row_path(str(row["key"]))
        # A per-writer temp name (two attempts of one cell may race); created by open(),
        # so the row's mode follows the umask like every other output file.
        with atomic_file(path, "w", unique=True) as handle:
            json.dump(dict(row), handle, indent=2, default=str)
            handle.write("\n")
        return path

    def rows(self) -> list[dict[str, Any]]:
        return [json.loads(p.read_text()) for p in sorted((self.path / ROWS_DIR).glob("*.json"))]

    def table(self) -> pd.DataFrame:
        """All rows as a DataFrame (one row per run), sorted by the grid axes."""
        rows = self.rows()
        if not rows:
            return pd.DataFrame(columns=["key", *AXES, "status"])
        frame = pd.DataFrame(rows)
        order = [c for c in ("preset", *AXES) if c in frame.columns]
        return frame.sort_values(order, key=lambda s: s.astype(str)).reset_index(drop=True)

    def __len__(self) -> int:
        return len(list((self.path / ROWS_DIR).glob("*.json")))
