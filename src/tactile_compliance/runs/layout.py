"""A run directory's names: what it is called, its config hash, the files it holds.

Training writes these files, evaluation and inference read them, and grids and tuning
name their runs with :func:`run_name`. The full layout of a run directory is described
in ``training/train.py``.
"""

from __future__ import annotations

import hashlib
import json

from tactile_compliance.config import ExperimentConfig, config_to_dict
from tactile_compliance.data.store import SAMPLE_COLUMNS

RESULT_FILE = "metrics.json"
BEST_FILE = "best.pt"
#: The columns of predictions.csv taken from the store: a sample's identity and label
#: ("sample_id" ... "modulus_pa"); the prediction follows as "pred_pa".
PREDICTION_COLUMNS = SAMPLE_COLUMNS[: SAMPLE_COLUMNS.index("modulus_pa") + 1]


def config_hash(cfg: ExperimentConfig) -> str:
    """Short hash of everything that changes a run's result (not where it is written)."""
    data = config_to_dict(cfg)
    data.pop("output_dir", None)
    for key in ("num_workers", "device"):
        data.get("training", {}).pop(key, None)
    return hashlib.sha256(json.dumps(data, sort_keys=True, default=str).encode()).hexdigest()[:10]


def run_name(cfg: ExperimentConfig) -> str:
    """Readable, unique run directory name: model-inputs-condition-sampling-seed-hash."""
    return (
        f"{cfg.model.name}-{cfg.inputs}-{cfg.split.condition}-{cfg.sampling.strategy}"
        f"-seed{cfg.seed}-{config_hash(cfg)}"
    )
