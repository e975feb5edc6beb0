"""Re-evaluate a trained run from its checkpoint, on its own test split or another store."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from tactile_compliance.config import config_from_dict
from tactile_compliance.data.dataset import GraspDataset
from tactile_compliance.data.normalisation import denormalise_modulus
from tactile_compliance.data.preprocess import filter_samples
from tactile_compliance.data.splits import Split
from tactile_compliance.data.store import GraspStore
from tactile_compliance.devices import DEFAULT_DEVICE
from tactile_compliance.runs.checkpoint import load_checkpoint
from tactile_compliance.runs.forward import predict_dataset
from tactile_compliance.runs.layout import BEST_FILE, PREDICTION_COLUMNS
from tactile_compliance.runs.metrics import compute_metrics, grouped_metrics


@dataclass
class Evaluation:
    """Predictions (one row per sample), overall metrics and per-group metrics."""

    predictions: pd.DataFrame
    metrics: dict[str, Any]
    groups: pd.DataFrame


def evaluate_run(
    run_dir: str | Path,
    store: str | Path | None = None,
    *,
    batch_size: int = 64,
    backbone_weights: str | Path | None = None,
    device: str = DEFAULT_DEVICE,
) -> Evaluation:
    """Metrics of a run's best checkpoint on its own test split (``split.json``: the
    numbers of ``metrics.json``), or on every sample of ``store`` that passes the run's
    sample filter. ``backbone_weights``: a local copy of a frozen backbone's weights file.

    Raises:
        ValueError: the checkpoint takes estimates (ALL inputs) and the store's are in
            other units (``RunInputs.check_sensor``, as ``predict`` and ``live`` refuse).
        StoreError: the store's rows are in two units.
    """
    run_dir = Path(run_dir)
    loaded = load_checkpoint(run_dir / BEST_FILE, device, backbone_weights=backbone_weights)
    cfg = config_from_dict(loaded.meta["config"])
    if store is None:
        if cfg.data.store is None:
            raise ValueError(f"{run_dir}: the run's config names no store; pass one")
        grasp_store = GraspStore.open(cfg.data.store)
        ids = Split.load(run_dir / "split.json").test_ids
    else:
        grasp_store = GraspStore.open(store)
        kept, _ = filter_samples(grasp_store.samples, cfg)
        ids = kept["sample_id"].to_numpy(dtype=np.int64)
    run_inputs = loaded.run_inputs
    # The check predict and live make: estimates in other units than the training data's.
    run_inputs.check_sensor(
        grasp_store.sensor_units,
        trained=f"checkpoint {run_dir / BEST_FILE}",
        used=f"store {grasp_store.path}",
    )
    constants = run_inputs.constants
    dataset = GraspDataset(grasp_store, ids, constants, run_inputs.inputs)
    predicted = predict_dataset(
        loaded.model, dataset, run_inputs, batch_size=batch_size, device=device
    )
    predictions = grasp_store.samples.iloc[ids][list(PREDICTION_COLUMNS)].reset_index(drop=True)
    predictions["pred_pa"] = denormalise_modulus(predicted.astype(np.float64), constants)
    metrics = compute_metrics(predictions["modulus_pa"], predictions["pred_pa"], constants)
    groups = grouped_metrics(predictions, c=constants)
    return Evaluation(predictions=predictions, metrics=metrics, groups=groups)
