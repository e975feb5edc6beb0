"""A run directory's names, and how its files are written and who may write them.

One process at a time trains in a run directory (it holds :data:`LOCK_FILE`). See
docs/training.md, "The run directory".
"""

from __future__ import annotations

import csv
import hashlib
import json
from pathlib import Path

from tactile_compliance.config import ConfigError, ExperimentConfig, config_to_dict
from tactile_compliance.data.store import SAMPLE_COLUMNS

RESULT_FILE = "metrics.json"
BEST_FILE = "best.pt"
#: Lightning's full training state after the last finished epoch, and the one before it.
CHECKPOINT_DIR = "checkpoints"
LAST_CHECKPOINT = "last.ckpt"
PREVIOUS_CHECKPOINT = "last.prev.ckpt"
#: The per-epoch log (train_loss, train_mse, val_nmse), relative to the run directory.
EPOCH_LOG = "logs/metrics.csv"
#: ``flock``-ed by the one process training in a run directory; records its holder.
LOCK_FILE = ".lock"
#: The columns of predictions.csv taken from the store: a sample's identity and label
#: ("sample_id" ... "modulus_pa"); the prediction follows as "pred_pa".
PREDICTION_COLUMNS = SAMPLE_COLUMNS[: SAMPLE_COLUMNS.index("modulus_pa") + 1]


def read_epoch_log(path: str | Path) -> list[tuple[int, dict[str, str]]]:
    """The lines of an epoch log (:data:`EPOCH_LOG`) with a readable epoch, as
    ``(epoch, line)``; a line without one is skipped (cut short by a kill, or a line that
    older versions wrote in place). An unreadable file raises what reading it raised.
    """
    with open(path, newline="", encoding="utf-8") as handle:
        rows = list(csv.DictReader(handle))
    out = []
    for row in rows:
        try:
            out.append((int(float(row.get("epoch") or "nan")), row))  # NaN raises too
        except ValueError:
            continue
    return out


def config_hash(cfg: ExperimentConfig) -> str:
    """Short hash of everything that changes a run's result (not where it is written)."""
    data = config_to_dict(cfg)
    data.pop("output_dir", None)
    for key in ("num_workers", "device"):
        data.get("training", {}).pop(key, None)
    return hashlib.sha256(json.dumps(data, sort_keys=True, default=str).encode()).hexdigest()[:10]


def run_name(cfg: ExperimentConfig) -> str:
    """Readable, unique run directory name: model-inputs-condition-sampling-seed-hash.

    The condition reads ``seen-per_sample`` for the paper's per-sample Seen split, so its
    runs stand apart from the leak-free grasp-grouped ones at a glance.
    """
    condition = cfg.split.condition
    if condition == "seen" and cfg.split.grouping == "per_sample":
        condition = "seen-per_sample"
    return (
        f"{cfg.model.name}-{cfg.inputs}-{condition}-{cfg.sampling.strategy}"
        f"-seed{cfg.seed}-{config_hash(cfg)}"
    )


#: The kind of a run directory in its ``outputs`` marker.
RUN_KIND = "run"

#: What a finished run keeps (``--keep-checkpoints``): ``best.pt`` and ``checkpoints/``
#: (all), ``best.pt`` only (best), nothing of either (none: the metrics and predictions).
KEEP_CHECKPOINTS = ("all", "best", "none")


def check_keep_checkpoints(keep: str) -> str:
    """``keep`` if it is one of :data:`KEEP_CHECKPOINTS`, else a ConfigError."""
    if keep not in KEEP_CHECKPOINTS:
        raise ConfigError(
            f"keep_checkpoints must be one of {', '.join(KEEP_CHECKPOINTS)}, got {keep!r}"
        )
    return keep


def prune_checkpoints(run_dir: str | Path, keep: str) -> None:
    """Delete the checkpoints of a finished run that ``keep`` does not keep.

    ``checkpoints/`` only serves to resume; ``best.pt`` is what ``evaluate`` and inference
    load. Deletes only these files of the run's own layout.
    """
    if check_keep_checkpoints(keep) == "all":
        return
    import shutil

    shutil.rmtree(Path(run_dir) / CHECKPOINT_DIR, ignore_errors=True)
    if keep == "none":
        (Path(run_dir) / BEST_FILE).unlink(missing_ok=True)
