"""``train(config) -> result``: the one training path used by single runs, grids and tuning.

One call: open the store, filter, split (saved), balance, build the model, optionally
cache frozen-backbone features, fit with early stopping on validation N-MSE, restore the
BEST epoch's weights, evaluate on the untouched test split, and write a run directory::

    RUN_DIR/
      config.yaml          the resolved configuration
      split.json           the sample ids of train / val / test (reloadable)
      filter_report.json   how many samples each filter rule removed
      checkpoints/last.ckpt  Lightning state for resuming an interrupted run
      best.pt              self-describing best checkpoint (see runs/checkpoint.py)
      logs/metrics.csv     per-epoch train loss and validation N-MSE
      predictions.csv      val + test predictions, one row per sample
      groups.csv           test metrics per material, shape, soft/hard
      metrics.json         the result returned by train()

A run whose ``metrics.json`` exists is complete and is returned as is; a run with only
``checkpoints/last.ckpt`` resumes from it.
"""

from __future__ import annotations

import json
import logging
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import pandas as pd
import torch
from lightning.pytorch.callbacks import Callback, EarlyStopping, ModelCheckpoint
from lightning.pytorch.loggers import CSVLogger
from torch.utils.data import DataLoader

from tactile_compliance.config import (
    ExperimentConfig,
    check_config_against_samples,
    config_to_dict,
    save_config,
)
from tactile_compliance.data.augment import GraspAugmentation
from tactile_compliance.data.balance import balance_split
from tactile_compliance.data.dataset import GraspDataset, batch_loader
from tactile_compliance.data.features import cached_features
from tactile_compliance.data.normalisation import NormalisationConstants, denormalise_modulus
from tactile_compliance.data.preprocess import filter_samples
from tactile_compliance.data.splits import Split, make_split_from_config
from tactile_compliance.data.store import GraspStore
from tactile_compliance.models import create_model, get_model_class
from tactile_compliance.runs.checkpoint import (
    FROZEN_BACKBONE_SEED,
    create_seeded_model,
    frozen_backbone_record,
    load_checkpoint,
    save_checkpoint,
)
from tactile_compliance.runs.forward import predict_dataset
from tactile_compliance.runs.layout import (
    BEST_FILE,
    PREDICTION_COLUMNS,
    RESULT_FILE,
    config_hash,
    run_name,
)
from tactile_compliance.runs.metrics import (
    compute_metrics,
    grouped_metrics,
    reference_predictions,
)
from tactile_compliance.training.module import ComplianceModule


@dataclass
class RunData:
    """Everything data-related a run needs, prepared once."""

    store: GraspStore
    samples: pd.DataFrame  # filtered
    filter_report: Any
    split: Split
    train_ids: np.ndarray  # after balancing (may repeat)
    val_ids: np.ndarray
    constants: NormalisationConstants
    image_size: tuple[int, int] | None


def prepare_data(cfg: ExperimentConfig, recommended_size: tuple[int, int] | None) -> RunData:
    """Filter, split and balance the configured store (no model involved)."""
    if cfg.data.store is None:
        raise ValueError(
            "data.store is not set: pass --set data.store=PATH or put it in the config"
        )
    store = GraspStore.open(cfg.data.store)
    check_config_against_samples(cfg, store.samples, store.header.source)
    samples, report = filter_samples(store.samples, cfg)
    if samples.empty:
        raise ValueError(f"no samples left after filtering {store.path}:\n{report}")
    split = make_split_from_config(samples, cfg)
    train_ids, val_ids = split.train_ids, split.val_ids
    if cfg.sampling.strategy == "balanced":
        train_ids, val_ids = balance_split(
            samples,
            split,
            cfg.sampling.t_balance,
            seed=cfg.seed,
            n_bins=cfg.sampling.n_bins,
            label_constants=cfg.normalisation_constants(),
            balance_validation=cfg.sampling.balance_validation,
        )
    image_size = cfg.data.image_size or recommended_size
    return RunData(
        store=store,
        samples=samples,
        filter_report=report,
        split=split,
        train_ids=np.asarray(train_ids, dtype=np.int64),
        val_ids=np.asarray(val_ids, dtype=np.int64),
        constants=cfg.normalisation_constants(),
        image_size=tuple(image_size) if image_size is not None else None,
    )


def build_model(cfg: ExperimentConfig) -> torch.nn.Module:
    """The configured model; a frozen random backbone is initialised from a fixed seed."""
    model_kwargs: dict[str, Any] = {"inputs": cfg.inputs, **cfg.model.hparams}
    if getattr(get_model_class(cfg.model.name), "pretrained_backbone", False):
        model_kwargs["backbone_weights"] = cfg.model.backbone_weights
    if cfg.model.freeze_backbone and cfg.model.backbone_weights.strip().lower() == "none":
        # The backbone comes from the fixed seed (shared by every run, so one feature
        # cache serves them all, and a head-only checkpoint can rebuild it); the head
        # keeps the run seed's initialisation.
        reference = create_seeded_model(cfg.model.name, FROZEN_BACKBONE_SEED, **model_kwargs)
        model = create_model(cfg.model.name, **model_kwargs)
        model.backbone.load_state_dict(reference.backbone.state_dict())
        return model
    return create_model(cfg.model.name, **model_kwargs)


class _BestCheckpoint(Callback):
    """Saves a self-describing checkpoint whenever validation N-MSE improves."""

    def __init__(self, save: Any) -> None:
        self.save = save
        self.best = float("inf")
        self.best_epoch = -1

    # on_validation_end, not on_validation_epoch_end: callbacks' epoch-end hooks run
    # before the LightningModule's, which is where val_nmse is logged.
    def on_validation_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.sanity_checking or "val_nmse" not in trainer.callback_metrics:
            return
        score = float(trainer.callback_metrics["val_nmse"])
        if score < self.best:
            self.best, self.best_epoch = score, trainer.current_epoch
            self.save({"best_val_nmse": score, "best_epoch": trainer.current_epoch})

    def state_dict(self) -> dict[str, Any]:
        return {"best": self.best, "best_epoch": self.best_epoch}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self.best = float(state_dict["best"])
        self.best_epoch = int(state_dict["best_epoch"])


def _accelerator(device: str) -> str:
    if device == "auto":
        return "gpu" if torch.cuda.is_available() else "cpu"
    return "gpu" if device.startswith("cuda") else device


def _loggers(run_dir: Path, tensorboard: bool) -> list[Any]:
    """CSV always (logs/metrics.csv); TensorBoard on request, with a clear error if absent."""
    # Flush every step: a killed run keeps the epochs it finished.
    loggers: list[Any] = [
        CSVLogger(save_dir=run_dir, name="", version="logs", flush_logs_every_n_steps=1)
    ]
    if tensorboard:
        try:
            from lightning.pytorch.loggers import TensorBoardLogger

            loggers.append(TensorBoardLogger(save_dir=run_dir, name="", version="tensorboard"))
        except ModuleNotFoundError as err:
            raise ValueError(
                "training.tensorboard=true needs the tensorboard package: pip install tensorboard"
            ) from err
    return loggers


def _predictions_frame(
    data: RunData, ids: np.ndarray, predicted: np.ndarray, split_name: str
) -> pd.DataFrame:
    rows = data.store.samples.iloc[ids][list(PREDICTION_COLUMNS)].reset_index(drop=True)
    rows["pred_pa"] = denormalise_modulus(predicted.astype(np.float64), data.constants)
    rows["split"] = split_name
    return rows


def evaluate_model(
    model: torch.nn.Module,
    data: RunData,
    features: np.ndarray | None,
    batch_size: int,
    device: str | torch.device = "cpu",
) -> tuple[pd.DataFrame, dict[str, Any]]:
    """Predictions on val and test, test metrics (overall, grouped, reference predictors)."""
    frames = []
    for name, ids in (("val", data.split.val_ids), ("test", data.split.test_ids)):
        dataset = GraspDataset(data.store, ids, data.constants, features)
        predicted = predict_dataset(
            model, dataset, data.constants, data.image_size, batch_size=batch_size, device=device
        )
        frames.append(_predictions_frame(data, ids, predicted, name))
    predictions = pd.concat(frames, ignore_index=True)
    test = predictions[predictions["split"] == "test"]
    val = predictions[predictions["split"] == "val"]
    reference = reference_predictions(
        data.store.samples.iloc[data.split.train_ids],
        data.store.samples.iloc[data.split.test_ids],
        data.constants,
    )
    metrics = {
        "test": compute_metrics(test["modulus_pa"], test["pred_pa"], data.constants),
        "val": compute_metrics(val["modulus_pa"], val["pred_pa"], data.constants),
        "reference": {
            name: compute_metrics(test["modulus_pa"].to_numpy(), values, data.constants)
            for name, values in reference.items()
        },
    }
    return predictions, metrics


def release_memory() -> None:
    """Free what a finished run left behind before the next run in the same process.

    Lightning's trainer, callbacks and module reference each other, so a run's model (half
    a gigabyte for VGG16) lives until a garbage-collection cycle; and glibc keeps freed
    arenas unless asked to return them. Grid workers run many cells in one process.
    """
    import contextlib
    import ctypes
    import gc

    gc.collect()
    with contextlib.suppress(OSError, AttributeError):  # not glibc (macOS, musl): no trim
        ctypes.CDLL("libc.so.6").malloc_trim(0)


def train(
    cfg: ExperimentConfig,
    *,
    run_dir: str | Path | None = None,
    progress: bool = True,
    overwrite: bool = False,
) -> dict[str, Any]:
    """Train and evaluate one configuration; returns the metrics dict (also metrics.json).

    Args:
        cfg: a validated experiment configuration.
        run_dir: where to write; default ``cfg.output_dir / run_name(cfg)``.
        progress: show progress bars.
        overwrite: retrain even when the run directory holds a finished result.
    """
    run_dir = Path(run_dir) if run_dir is not None else Path(cfg.output_dir) / run_name(cfg)
    result_path = run_dir / RESULT_FILE
    if result_path.exists() and not overwrite:
        return json.loads(result_path.read_text())
    try:
        return _train(cfg, run_dir, progress=progress, overwrite=overwrite)
    finally:
        release_memory()


def _train(
    cfg: ExperimentConfig, run_dir: Path, *, progress: bool, overwrite: bool
) -> dict[str, Any]:
    started = time.perf_counter()
    result_path = run_dir / RESULT_FILE
    run_dir.mkdir(parents=True, exist_ok=True)
    if overwrite:
        for stale in (result_path, run_dir / "checkpoints" / "last.ckpt", run_dir / BEST_FILE):
            stale.unlink(missing_ok=True)
    save_config(cfg, run_dir / "config.yaml")

    L.seed_everything(cfg.seed, workers=True, verbose=False)
    model = build_model(cfg)
    data = prepare_data(cfg, getattr(model, "recommended_image_size", None))
    data.split.save(run_dir / "split.json")
    (run_dir / "filter_report.json").write_text(
        json.dumps(data.filter_report.to_dict(), indent=2, default=str) + "\n"
    )

    device = "cuda" if _accelerator(cfg.training.device) == "gpu" else "cpu"
    features = None
    augmentation = None
    # A frozen backbone is recorded (how to rebuild it + its sha256), not saved: best.pt
    # then holds the head only. Recorded now, as the backbone the features come from.
    frozen_backbone = (
        frozen_backbone_record(model, seed=FROZEN_BACKBONE_SEED)
        if cfg.model.freeze_backbone
        else None
    )
    if cfg.model.freeze_backbone:
        if cfg.augmentation.enabled:
            warnings.warn(
                "augmentation is ignored with freeze_backbone: features are cached from "
                "un-augmented frames (set augmentation.enabled=false to silence this)",
                stacklevel=2,
            )
        features = cached_features(
            data.store,
            model.backbone,
            data.image_size,
            data.constants,
            batch_size=max(8, cfg.training.batch_size),
            device=device,
            progress=progress,
        )
    elif cfg.augmentation.enabled:
        augmentation = GraspAugmentation.from_config(cfg.augmentation, seed=cfg.seed)

    def loader(ids: np.ndarray, shuffle: bool) -> DataLoader:
        return batch_loader(
            GraspDataset(data.store, ids, data.constants, features),
            cfg.training.batch_size,
            shuffle=shuffle,
            num_workers=cfg.training.num_workers,
        )

    module = ComplianceModule(
        model,
        data.constants,
        data.image_size,
        lr=cfg.training.lr,
        gamma=cfg.training.gamma,
        l2_weight=cfg.training.l2_weight,
        augmentation=augmentation,
        freeze_backbone=cfg.model.freeze_backbone,
        finetune=cfg.model.finetune,
        compile_model=cfg.training.compile,
    )
    config_dict = config_to_dict(cfg)

    def save_best(extra: dict[str, Any]) -> None:
        save_checkpoint(
            run_dir / BEST_FILE,
            model,
            constants=data.constants,
            image_size=data.image_size,
            config=config_dict,
            seed=cfg.seed,
            metrics=extra,
            frozen_backbone=frozen_backbone,
            store_image_size=data.store.image_size,
        )

    best = _BestCheckpoint(save_best)
    last = ModelCheckpoint(dirpath=run_dir / "checkpoints", save_last=True, save_top_k=0)
    callbacks: list[Callback] = [best, last]
    if cfg.training.patience > 0:
        callbacks.append(EarlyStopping("val_nmse", patience=cfg.training.patience, mode="min"))
    # Before the Trainer exists: it prints its start-up messages when created.
    logging.getLogger("lightning.pytorch").setLevel(logging.INFO if progress else logging.WARNING)
    accelerator = _accelerator(cfg.training.device)
    trainer = L.Trainer(
        max_epochs=cfg.training.max_epochs,
        accelerator=accelerator,
        devices=1,
        precision=cfg.training.precision,
        deterministic=accelerator == "cpu",
        callbacks=callbacks,
        logger=_loggers(run_dir, cfg.training.tensorboard),
        enable_progress_bar=progress,
        enable_model_summary=False,
        num_sanity_val_steps=0,
        log_every_n_steps=1,
        limit_train_batches=cfg.training.limit_batches or 1.0,
        limit_val_batches=cfg.training.limit_batches or 1.0,
    )
    resume_from = run_dir / "checkpoints" / "last.ckpt"
    epoch_log = run_dir / "logs" / "metrics.csv"
    # Lightning's CSV logger starts a new file in a new process: keep the earlier epochs.
    earlier_log = pd.read_csv(epoch_log) if resume_from.exists() and epoch_log.exists() else None
    trainer.fit(
        module,
        train_dataloaders=loader(data.train_ids, shuffle=True),
        val_dataloaders=loader(data.val_ids, shuffle=False),
        ckpt_path=resume_from if resume_from.exists() else None,
    )
    if earlier_log is not None and epoch_log.exists():
        merged = pd.concat([earlier_log, pd.read_csv(epoch_log)], ignore_index=True)
        merged.to_csv(epoch_log, index=False)

    # Test with the BEST epoch's weights, never the last epoch's.
    best_model = load_checkpoint(run_dir / BEST_FILE, device=device).model
    predictions, metrics = evaluate_model(
        best_model, data, features, batch_size=max(64, cfg.training.batch_size), device=device
    )
    predictions.to_csv(run_dir / "predictions.csv", index=False)
    test_rows = predictions[predictions["split"] == "test"]
    grouped_metrics(test_rows, c=data.constants).to_csv(run_dir / "groups.csv", index=False)

    result: dict[str, Any] = {
        "status": "complete",
        "run_name": run_dir.name,
        "run_dir": str(run_dir),
        "model": cfg.model.name,
        "inputs": cfg.inputs,
        "condition": cfg.split.condition,
        "sampling": cfg.sampling.strategy,
        "seed": cfg.seed,
        "config_hash": config_hash(cfg),
        "backbone_weights": str(getattr(model, "backbone_weights", "none")),
        "freeze_backbone": cfg.model.freeze_backbone,
        "image_size": list(data.image_size) if data.image_size else None,
        "n_train": len(data.train_ids),
        "n_val": len(data.val_ids),
        "n_test": len(data.split.test_ids),
        "best_epoch": best.best_epoch,
        "best_val_nmse": best.best,
        "epochs_trained": trainer.current_epoch,
        "wall_time_s": round(time.perf_counter() - started, 2),
        **metrics,
    }
    tmp = result_path.with_suffix(".tmp")
    tmp.write_text(json.dumps(result, indent=2) + "\n")
    tmp.replace(result_path)
    return result
