"""``train(config) -> result``: the one training path used by single runs, grids and tuning.

The resume engine (epoch-end checkpoints, their commit, where a re-run starts) is
:mod:`tactile_compliance.training.resume`. See docs/training.md ("What one run does",
"The run directory", "Interrupted runs resume exactly").
"""

from __future__ import annotations

import contextlib
import json
import logging
import signal
import sys
import threading
import time
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import pandas as pd
import torch
from lightning.pytorch.callbacks import Callback, EarlyStopping
from torch.utils.data import DataLoader

from tactile_compliance.config import ExperimentConfig, config_to_dict, save_config
from tactile_compliance.data.augment import GraspAugmentation
from tactile_compliance.data.balance import balance_split
from tactile_compliance.data.dataset import GraspDataset, batch_loader
from tactile_compliance.data.features import cached_features
from tactile_compliance.data.normalisation import denormalise_modulus
from tactile_compliance.data.preprocess import filter_samples
from tactile_compliance.data.splits import (
    Split,
    check_split_store,
    make_split_from_config,
    store_metadata,
)
from tactile_compliance.data.store import GraspStore
from tactile_compliance.devices import DEFAULT_DEVICE, resolve_device
from tactile_compliance.models import create_model, get_model_class
from tactile_compliance.models.frame_rules import too_small_message
from tactile_compliance.outputs import atomic_file, claim_output_dir, exclusive_lock
from tactile_compliance.runs.checkpoint import (
    FROZEN_BACKBONE_SEED,
    backbone_weights_file_record,
    create_seeded_model,
    frozen_backbone_record,
    load_checkpoint,
    save_checkpoint,
)
from tactile_compliance.runs.config_checks import check_config_against_samples
from tactile_compliance.runs.forward import predict_dataset
from tactile_compliance.runs.layout import (
    BEST_FILE,
    CHECKPOINT_DIR,
    EPOCH_LOG,
    LAST_CHECKPOINT,
    LOCK_FILE,
    PREDICTION_COLUMNS,
    PREVIOUS_CHECKPOINT,
    RESULT_FILE,
    RUN_KIND,
    config_hash,
    run_name,
)
from tactile_compliance.runs.metrics import (
    compute_metrics,
    grouped_metrics,
    reference_predictions,
)
from tactile_compliance.runs.run_inputs import RunInputs
from tactile_compliance.training.module import ComplianceModule
from tactile_compliance.training.resume import (
    PENDING_BEST,
    BestCheckpoint,
    EpochLog,
    EpochState,
    find_resume_point,
    read_earlier_rows,
)


@dataclass
class RunData:
    """Everything data-related a run needs, prepared once."""

    store: GraspStore
    filter_report: Any
    split: Split
    train_ids: np.ndarray  # after balancing (may repeat)
    val_ids: np.ndarray
    run_inputs: RunInputs  # resolved here, once; stored in best.pt


def prepare_data(cfg: ExperimentConfig, model: torch.nn.Module) -> RunData:
    """Filter, split and balance the configured store, and resolve the run's
    :class:`~tactile_compliance.runs.run_inputs.RunInputs` for ``model``."""
    if cfg.data.store is None:
        raise ValueError(
            "data.store is not set: pass --set data.store=PATH or put it in the config"
        )
    store = GraspStore.open(cfg.data.store)
    run_inputs = RunInputs.resolve(cfg, store, model)
    check_config_against_samples(cfg, store.samples, store.header.source)
    samples, report = filter_samples(store.samples, cfg)
    if samples.empty:
        raise ValueError(f"no samples left after filtering {store.path}:\n{report}")
    if cfg.split.file is not None:  # train --split FILE: the saved split, not a new one
        split = Split.load(cfg.split.file)
        check_split_store(split, cfg.split.file, store, samples)
    else:
        split = make_split_from_config(samples, cfg, store_metadata(store))
    train_ids, val_ids = split.train_ids, split.val_ids
    if cfg.sampling.strategy == "balanced":
        train_ids, val_ids = balance_split(
            samples,
            split,
            cfg.sampling.t_balance,
            seed=cfg.seed,
            n_bins=cfg.sampling.n_bins,
            label_constants=run_inputs.constants,
            balance_validation=cfg.sampling.balance_validation,
        )
    return RunData(
        store=store,
        filter_report=report,
        split=split,
        train_ids=np.asarray(train_ids, dtype=np.int64),
        val_ids=np.asarray(val_ids, dtype=np.int64),
        run_inputs=run_inputs,
    )


def check_frame_size(
    cfg: ExperimentConfig, model: torch.nn.Module, size: tuple[int, int] | None
) -> None:
    """A ValueError before the run starts, not in Lightning's first step, when its images
    ((H, W) px; None: a frame-free run, nothing to check) are smaller than the model
    accepts (``TactileModel.min_image_size``, the one rule)."""
    if size is None:
        return
    minimum = int(model.min_image_size)
    height, width = (int(n) for n in size)
    if min(height, width) >= minimum:
        return
    origin = "data.image_size is" if cfg.data.image_size else "the store's frames are"
    raise ValueError(too_small_message(cfg.model.name, minimum, origin, (height, width)))


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


def _accelerator(device: str) -> str:
    """Lightning's accelerator for ``training.device``; a missing GPU is a clear error."""
    resolved = str(resolve_device(device, name="training.device"))
    return "gpu" if resolved.startswith("cuda") else resolved


def _tensorboard_logger(run_dir: Path, tensorboard: bool) -> Any:
    """TensorBoard's logger on request (writes nothing yet), with a clear error if absent."""
    if not tensorboard:
        return None
    try:
        from lightning.pytorch.loggers import TensorBoardLogger

        return TensorBoardLogger(save_dir=run_dir, name="", version="tensorboard")
    except ModuleNotFoundError as err:
        raise ValueError(
            "training.tensorboard=true needs the tensorboard package: pip install tensorboard"
        ) from err


def frozen_features(
    cfg: ExperimentConfig,
    store: GraspStore,
    model: torch.nn.Module,
    run_inputs: RunInputs,
    *,
    progress: bool,
) -> np.ndarray:
    """The frozen backbone's features of every store sample, computed once and cached
    (``data.features``); ``precompute_features`` asks for the same cache as ``train``."""
    return cached_features(
        store,
        model.backbone,
        run_inputs.image_size,
        run_inputs.constants,
        image=run_inputs.inputs.image.name,
        batch_size=max(8, cfg.training.batch_size),
        device="cuda" if _accelerator(cfg.training.device) == "gpu" else "cpu",
        progress=progress,
    )


def evaluate_model(
    model: torch.nn.Module,
    data: RunData,
    features: np.ndarray | None,
    batch_size: int,
    device: str | torch.device = DEFAULT_DEVICE,
    *,
    seed: int = 0,
) -> tuple[pd.DataFrame, dict[str, Any]]:
    """Predictions on val and test, test metrics (overall, grouped, reference predictors).

    The run's input strategy (``data.run_inputs.inputs``) adds the scalar reference on its
    scalar inputs (none for Image), fitted with ``random_state=seed``; the references are
    fitted on the split's training rows (before balancing) and scored on its test rows.
    """
    run_inputs = data.run_inputs
    constants = run_inputs.constants
    frames = []
    for name, ids in (("val", data.split.val_ids), ("test", data.split.test_ids)):
        dataset = GraspDataset(data.store, ids, constants, run_inputs.inputs, features)
        predicted = predict_dataset(
            model, dataset, run_inputs, batch_size=batch_size, device=device
        )
        rows = data.store.samples.iloc[ids][list(PREDICTION_COLUMNS)].reset_index(drop=True)
        rows["pred_pa"] = denormalise_modulus(predicted.astype(np.float64), constants)
        rows["split"] = name
        frames.append(rows)
    predictions = pd.concat(frames, ignore_index=True)
    test = predictions[predictions["split"] == "test"]
    val = predictions[predictions["split"] == "val"]
    reference = reference_predictions(
        data.store.samples.iloc[data.split.train_ids],
        data.store.samples.iloc[data.split.test_ids],
        constants,
        inputs=data.run_inputs.inputs,
        seed=seed,
    )
    metrics = {
        "test": compute_metrics(test["modulus_pa"], test["pred_pa"], constants),
        "val": compute_metrics(val["modulus_pa"], val["pred_pa"], constants),
        "reference": {
            name: compute_metrics(test["modulus_pa"].to_numpy(), values, constants)
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
    import ctypes
    import gc

    gc.collect()
    with contextlib.suppress(OSError, AttributeError):  # not glibc (macOS, musl): no trim
        ctypes.CDLL("libc.so.6").malloc_trim(0)


def _finished_result(run_dir: Path) -> dict[str, Any] | None:
    try:
        return json.loads((run_dir / RESULT_FILE).read_text())
    except FileNotFoundError:
        return None


#: Lightning's loggers: its start-up and housekeeping messages ("GPU available", the
#: litlogger tip, the batch limits, "`weights_only` was not set", "fit stopped") are INFO.
LIGHTNING_LOGGERS = ("lightning.pytorch", "lightning.fabric")


def quiet_lightning_warnings() -> None:
    """Ignore the warnings about Lightning's own code and advice that say nothing about a
    run (deprecations inside Lightning, loader workers, logging intervals, a checkpoint
    folder that exists because the run resumes). Adds to the current warning filters."""
    warnings.filterwarnings("ignore", category=DeprecationWarning, module="lightning.*")
    warnings.filterwarnings("ignore", message=".*LeafSpec.*")
    warnings.filterwarnings("ignore", message=".*exists and is not empty.*")
    warnings.filterwarnings("ignore", message=".*does not have many workers.*")
    warnings.filterwarnings("ignore", message=".*number of training batches.*")


@contextlib.contextmanager
def lightning_messages(verbose: bool) -> Iterator[None]:
    """Lightning's INFO messages and housekeeping warnings inside only when ``verbose``;
    warnings about the run itself and errors show either way."""
    loggers = [logging.getLogger(name) for name in LIGHTNING_LOGGERS]
    levels = [logger.level for logger in loggers]
    with warnings.catch_warnings():
        if not verbose:
            quiet_lightning_warnings()
        for logger in loggers:
            logger.setLevel(logging.INFO if verbose else logging.WARNING)
        try:
            yield
        finally:
            for logger, level in zip(loggers, levels, strict=True):
                logger.setLevel(level)


def train(
    cfg: ExperimentConfig,
    *,
    run_dir: str | Path | None = None,
    progress: bool = True,
    overwrite: bool = False,
    verbose: bool = False,
) -> dict[str, Any]:
    """Train and evaluate one configuration; returns the metrics dict (also metrics.json).

    A run whose ``metrics.json`` exists is complete and is returned as is (unless
    ``overwrite``). A configuration or store that fails its checks writes nothing, not
    even the run directory.

    Resumes an interrupted run from its last finished epoch (docs/training.md), and says
    so in one line on stderr whatever ``verbose`` (:func:`resume_line`); ``metrics.json``
    lists the epoch each resume started from (``resumed_from_epoch``, empty: never
    interrupted).

    Args:
        run_dir: where to write; default ``cfg.output_dir / run_name(cfg)``.
        overwrite: retrain even when the run directory holds a finished result.
        verbose: show Lightning's start-up messages and its housekeeping warnings
            (:func:`lightning_messages`).

    Raises:
        DirectoryLockedError: another process is training in ``run_dir``.
        KeyboardInterrupt: Ctrl-C; re-running continues after the last finished epoch.
    """
    run_dir = Path(run_dir) if run_dir is not None else Path(cfg.output_dir) / run_name(cfg)
    if run_dir.is_dir():  # a run directory of ours, never a directory of someone's files
        claim_output_dir(run_dir, RUN_KIND, option="--out")
    if not overwrite and (finished := _finished_result(run_dir)) is not None:
        return finished
    started = time.perf_counter()
    lock = run_dir / LOCK_FILE
    try:
        with lightning_messages(verbose), contextlib.ExitStack() as stack:
            # An existing run directory is locked before anything else, so a second process
            # fails at once; a new one only after the configuration and the store passed
            # every check, so that a failed check leaves no directory behind.
            locked = run_dir.is_dir()
            if locked:  # checked above: it is ours
                stack.enter_context(exclusive_lock(lock, "run directory", wait=False))
            _accelerator(cfg.training.device)  # a missing GPU fails before anything is written
            tensorboard = _tensorboard_logger(run_dir, cfg.training.tensorboard)
            L.seed_everything(cfg.seed, workers=True, verbose=False)
            model = build_model(cfg)
            data = prepare_data(cfg, model)
            check_frame_size(cfg, model, data.run_inputs.image_size)
            if not locked:
                claim_output_dir(run_dir, RUN_KIND, option="--out")
                stack.enter_context(exclusive_lock(lock, "run directory", wait=False))
            # Another process may have finished this run while this one prepared its data.
            if not overwrite and (finished := _finished_result(run_dir)) is not None:
                return finished
            return _fit_and_evaluate(
                cfg, run_dir, model, data, tensorboard, started, progress, overwrite
            )
        raise AssertionError("unreachable")  # pragma: no cover - the with block returns
    finally:
        release_memory()


def resume_line(run_dir: Path, epochs_done: int, max_epochs: int) -> str:
    """``resuming RUN after epoch N of M``: ``N`` epochs of ``max_epochs`` are finished and
    the run continues with epoch ``N`` (0-based, as ``logs/metrics.csv`` counts)."""
    return f"resuming {run_dir} after epoch {epochs_done} of {max_epochs}"


def _fit_and_evaluate(
    cfg: ExperimentConfig,
    run_dir: Path,
    model: torch.nn.Module,
    data: RunData,
    tensorboard: Any,
    started: float,
    progress: bool,
    overwrite: bool,
) -> dict[str, Any]:
    """The part of a run that writes the run directory (held locked by the caller)."""
    result_path = run_dir / RESULT_FILE
    checkpoint_dir = run_dir / CHECKPOINT_DIR
    pending_best = checkpoint_dir / PENDING_BEST
    if overwrite:  # only files that training writes
        for stale in (
            result_path,
            run_dir / BEST_FILE,
            checkpoint_dir / LAST_CHECKPOINT,
            checkpoint_dir / PREVIOUS_CHECKPOINT,
            pending_best,
        ):
            stale.unlink(missing_ok=True)
    save_config(cfg, run_dir / "config.yaml")
    data.split.save(run_dir / "split.json")
    with atomic_file(run_dir / "filter_report.json") as handle:
        handle.write(json.dumps(data.filter_report.to_dict(), indent=2, default=str) + "\n")
    checkpoint_dir.mkdir(exist_ok=True)
    resume = find_resume_point(run_dir)
    earlier_rows = read_earlier_rows(run_dir / EPOCH_LOG, resume.epochs_done) if resume else []
    if resume is not None:  # quiet or not: a resume must never pass for a fresh start
        line = resume_line(run_dir, resume.epochs_done, cfg.training.max_epochs)
        print(line, file=sys.stderr, flush=True)

    accelerator = _accelerator(cfg.training.device)
    device = "cuda" if accelerator == "gpu" else "cpu"
    features = None
    augmentation = None
    # A frozen backbone is recorded (how to rebuild it + its sha256), not saved: best.pt
    # then holds the head only. Recorded now, as the backbone the features come from.
    frozen_backbone = (
        frozen_backbone_record(model, seed=FROZEN_BACKBONE_SEED)
        if cfg.model.freeze_backbone
        else None
    )
    # The weights file (e.g. from `pretrain`) the backbone started from: sha256 + provenance.
    weights_file = backbone_weights_file_record(model)
    if cfg.model.freeze_backbone:
        # (Augmentation is ignored here; the config's validation already warned.)
        features = frozen_features(cfg, data.store, model, data.run_inputs, progress=progress)
    elif cfg.augmentation.enabled and data.run_inputs.inputs.uses("frames"):
        # The photometric pipeline is for RGB frames: depth maps and scalars go unchanged.
        augmentation = GraspAugmentation.from_config(cfg.augmentation, seed=cfg.seed)

    def loader(ids: np.ndarray, shuffle: bool) -> DataLoader:
        return batch_loader(
            GraspDataset(
                data.store, ids, data.run_inputs.constants, data.run_inputs.inputs, features
            ),
            cfg.training.batch_size,
            shuffle=shuffle,
            num_workers=cfg.training.num_workers,
        )

    module = ComplianceModule(
        model,
        data.run_inputs,
        lr=cfg.training.lr,
        gamma=cfg.training.gamma,
        l2_weight=cfg.training.l2_weight,
        augmentation=augmentation,
        freeze_backbone=cfg.model.freeze_backbone,
        finetune=cfg.model.finetune,
        compile_model=cfg.training.compile,
        estimate_dropout=cfg.training.estimate_dropout,
        seed=cfg.seed,
    )
    config_dict = config_to_dict(cfg)

    def save_best(path: Path, extra: dict[str, Any]) -> None:
        save_checkpoint(
            path,
            model,
            run_inputs=data.run_inputs,
            config=config_dict,
            seed=cfg.seed,
            metrics=extra,
            backbone_weights_file=weights_file,
            frozen_backbone=frozen_backbone,
            store={"path": str(Path(data.store.path).resolve()), **data.store.header.to_dict()},
        )

    best = BestCheckpoint(save_best, pending_best)
    epoch_state = EpochState(checkpoint_dir, run_dir / BEST_FILE, pending_best)
    callbacks: list[Callback] = [best, epoch_state]
    if cfg.training.patience > 0:
        callbacks.append(EarlyStopping("val_nmse", patience=cfg.training.patience, mode="min"))
    trainer = L.Trainer(
        max_epochs=cfg.training.max_epochs,
        accelerator=accelerator,
        devices=1,
        precision=cfg.training.precision,
        deterministic=accelerator == "cpu",
        callbacks=callbacks,
        logger=[EpochLog(run_dir, earlier_rows), *([tensorboard] if tensorboard else [])],
        enable_progress_bar=progress,
        enable_model_summary=False,
        num_sanity_val_steps=0,
        log_every_n_steps=1,
        limit_train_batches=cfg.training.limit_batches or 1.0,
        limit_val_batches=cfg.training.limit_batches or 1.0,
    )
    _fit(
        trainer,
        module,
        loader(data.train_ids, shuffle=True),
        loader(data.val_ids, shuffle=False),
        resume.path if resume is not None else None,
    )

    # Test with the BEST epoch's weights, never the last epoch's.
    best_model = load_checkpoint(run_dir / BEST_FILE, device=device).model
    predictions, metrics = evaluate_model(
        best_model,
        data,
        features,
        batch_size=max(64, cfg.training.batch_size),
        device=device,
        seed=cfg.seed,
    )
    with atomic_file(run_dir / "predictions.csv") as handle:
        predictions.to_csv(handle, index=False)
    test_rows = predictions[predictions["split"] == "test"]
    with atomic_file(run_dir / "groups.csv") as handle:
        grouped_metrics(test_rows, c=data.run_inputs.constants).to_csv(handle, index=False)

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
        "backbone_weights_sha256": weights_file["sha256"] if weights_file else None,
        "freeze_backbone": cfg.model.freeze_backbone,
        "image_size": None
        if data.run_inputs.image_size is None
        else list(data.run_inputs.image_size),
        "n_train": len(data.train_ids),
        "n_val": len(data.val_ids),
        "n_test": len(data.split.test_ids),
        # train --split FILE: the saved split it used (None: drawn with the run's seed).
        "split_file": cfg.split.file,
        "best_epoch": best.best_epoch,
        "best_val_nmse": best.best,
        # A run resumed after early stopping trains nothing, and Lightning then leaves
        # current_epoch one short.
        "epochs_trained": max(trainer.current_epoch, epoch_state.epochs_done),
        "resumed_from_epoch": epoch_state.resumed_from_epoch,
        "wall_time_s": round(time.perf_counter() - started, 2),
        **metrics,
    }
    with atomic_file(result_path) as handle:
        handle.write(json.dumps(result, indent=2) + "\n")
    return result


def _fit(
    trainer: L.Trainer,
    module: ComplianceModule,
    train_loader: DataLoader,
    val_loader: DataLoader,
    resume_from: Path | None,
) -> None:
    """``trainer.fit``, resuming from ``resume_from``; Ctrl-C raises KeyboardInterrupt.

    On Ctrl-C Lightning ignores SIGINT from then on and calls ``sys.exit(1)``; the
    handler is put back and the interruption reported as what it is.
    """
    in_main_thread = threading.current_thread() is threading.main_thread()
    sigint = signal.getsignal(signal.SIGINT) if in_main_thread else None
    try:
        trainer.fit(
            module,
            train_dataloaders=train_loader,
            val_dataloaders=val_loader,
            ckpt_path=resume_from,
            weights_only=True,
        )
    except SystemExit:
        if trainer.interrupted:
            raise KeyboardInterrupt from None
        raise
    finally:
        if sigint is not None:
            signal.signal(signal.SIGINT, sigint)
