"""``train(config) -> result``: the one training path used by single runs, grids and tuning.

One call: open the store, filter, split (saved), balance, build the model, optionally
cache frozen-backbone features, fit with early stopping on validation N-MSE, restore the
BEST epoch's weights, evaluate on the untouched test split, and write a run directory::

    RUN_DIR/
      .lock                flock-ed by the one process training here (holder's PID)
      config.yaml          the resolved configuration
      split.json           the sample ids of train / val / test (reloadable)
      filter_report.json   how many samples each filter rule removed
      checkpoints/last.ckpt       Lightning's full state after the last finished epoch
      checkpoints/last.prev.ckpt  the same one epoch earlier (if last.ckpt is unreadable)
      best.pt              self-describing best checkpoint (see runs/checkpoint.py)
      logs/metrics.csv     per-epoch train loss and validation N-MSE
      predictions.csv      val + test predictions, one row per sample
      groups.csv           test metrics per material, shape, soft/hard
      metrics.json         the result returned by train()

A run whose ``metrics.json`` exists is complete and is returned as is. Any other run
resumes after its last finished epoch (``checkpoints/last.ckpt``, written atomically at
the end of every epoch) and ends with exactly the result of an uninterrupted run: the
global RNG states, the augmentation generator and every callback's state are part of the
checkpoint. A configuration or store that fails its checks writes nothing (not even the
run directory); a second process on the same run directory fails at once
(:class:`~tactile_compliance.runs.layout.DirectoryLockedError`).
"""

from __future__ import annotations

import contextlib
import csv
import json
import logging
import os
import random
import shutil
import signal
import threading
import time
import warnings
import zipfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import pandas as pd
import torch
from lightning.pytorch.callbacks import Callback, Checkpoint, EarlyStopping
from lightning.pytorch.loggers import Logger
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
from tactile_compliance.models.inputs import InputStrategy
from tactile_compliance.outputs import atomic_file, claim_output_dir, fsync_directory
from tactile_compliance.runs.checkpoint import (
    FROZEN_BACKBONE_SEED,
    backbone_weights_file_record,
    create_seeded_model,
    frozen_backbone_record,
    load_checkpoint,
    save_checkpoint,
    torch_write_errors,
)
from tactile_compliance.runs.forward import predict_dataset
from tactile_compliance.runs.layout import (
    BEST_FILE,
    CHECKPOINT_DIR,
    EPOCH_LOG,
    LAST_CHECKPOINT,
    PREDICTION_COLUMNS,
    PREVIOUS_CHECKPOINT,
    RESULT_FILE,
    RUN_KIND,
    config_hash,
    is_legacy_run_dir,
    lock_directory,
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


def check_frame_size(cfg: ExperimentConfig, model: torch.nn.Module, size: tuple[int, int]) -> None:
    """Fail before a run starts when its frames ((H, W) px) are smaller than the model's
    backbone accepts (``TactileModel.min_image_size``, declared by the backbone class,
    e.g. 65 px for Top10NN's unpadded convolutions), instead of in Lightning's first step.

    Raises:
        ValueError: one line naming the model, the size and the setting to change.
    """
    minimum = int(getattr(model, "min_image_size", 1))
    height, width = (int(n) for n in size)
    if min(height, width) >= minimum:
        return
    origin = "data.image_size is" if cfg.data.image_size else "the store's frames are"
    raise ValueError(
        f"{cfg.model.name} needs frames of at least {minimum}x{minimum} px, but {origin} "
        f"{height}x{width}: set data.image_size to [{max(height, minimum)}, "
        f"{max(width, minimum)}] or larger"
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


# ======================================================================= resumable state
#
# What a kill or Ctrl-C can lose is the epoch in progress, nothing before it:
#
# * at the end of every epoch (on_train_epoch_end) Lightning's full checkpoint is written
#   to ``checkpoints/last.ckpt.tmp``: weights, optimiser, scheduler, the loops' progress,
#   every callback's state (the best-epoch tracker, early stopping, _EpochState below with
#   the global RNG states and ``should_stop``) and the augmentation generator;
# * it is *committed* once Lightning has finished the epoch's bookkeeping (scheduler step,
#   the epoch's log rows), i.e. at the next epoch's start or at the end of training: it is
#   fsynced, the committed ``last.ckpt`` becomes ``last.prev.ckpt`` (a hard link, so a
#   ``last.ckpt`` exists at every instant), the temp file is renamed to ``last.ckpt`` and
#   a new best epoch's weights (``checkpoints/best.pending.pt``) become ``best.pt``.
#
# A re-run resumes from ``last.ckpt`` (or ``last.prev.ckpt`` if that one is unreadable)
# and, because the RNG states are restored where the uninterrupted run was at that
# moment, computes exactly what the uninterrupted run would have.

PENDING_BEST = "best.pending.pt"
_STAGED_SUFFIX = ".tmp"


def _rng_states() -> dict[str, Any]:
    """The global RNG states (torch, CUDA if in use, numpy, Python) as plain values and
    tensors, so the checkpoint still loads with ``torch.load(weights_only=True)``."""
    version, state, gauss = random.getstate()
    _, keys, pos, has_gauss, cached = np.random.get_state()
    states: dict[str, Any] = {
        "torch": torch.get_rng_state(),
        "numpy": {
            "keys": torch.from_numpy(np.asarray(keys, dtype=np.int64)),
            "pos": int(pos),
            "has_gauss": int(has_gauss),
            "cached_gaussian": float(cached),
        },
        "python": {"version": version, "state": list(state), "gauss": gauss},
    }
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        states["cuda"] = torch.cuda.get_rng_state_all()
    return states


def _set_rng_states(states: dict[str, Any]) -> None:
    torch.set_rng_state(states["torch"])
    if states.get("cuda") and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(states["cuda"])
    numpy_state = states["numpy"]
    np.random.set_state(
        (
            "MT19937",
            numpy_state["keys"].numpy().astype(np.uint32),
            numpy_state["pos"],
            numpy_state["has_gauss"],
            numpy_state["cached_gaussian"],
        )
    )
    python_state = states["python"]
    random.setstate((python_state["version"], tuple(python_state["state"]), python_state["gauss"]))


class _BestCheckpoint(Callback):
    """Tracks the best validation N-MSE and writes that epoch's self-describing checkpoint.

    The checkpoint goes to ``checkpoints/best.pending.pt``; :class:`_EpochState` turns it
    into ``best.pt`` when it commits the epoch, so ``best.pt`` always belongs to the
    committed training state (a run killed before the commit redoes the epoch).
    """

    def __init__(self, save: Callable[[Path, dict[str, Any]], None], pending: Path) -> None:
        self.save = save
        self.pending = pending
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
            self.save(self.pending, {"best_val_nmse": score, "best_epoch": trainer.current_epoch})

    def state_dict(self) -> dict[str, Any]:
        return {"best": self.best, "best_epoch": self.best_epoch}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self.best = float(state_dict["best"])
        self.best_epoch = int(state_dict["best_epoch"])


class _EpochState(Checkpoint):
    """Writes Lightning's full checkpoint at the end of every epoch (see above).

    A ``Checkpoint`` subclass: Lightning then adds no ModelCheckpoint of its own, and runs
    this callback's epoch-end hook after early stopping's and the module's, so the saved
    state includes this epoch's early-stopping decision and train metrics.
    """

    def __init__(self, directory: Path, best_file: Path, pending_best: Path) -> None:
        self.directory = directory
        self.best_file = best_file
        self.pending_best = pending_best
        self.last = directory / LAST_CHECKPOINT
        self.previous = directory / PREVIOUS_CHECKPOINT
        self.staged = directory / (LAST_CHECKPOINT + _STAGED_SUFFIX)
        #: Epochs finished, this process's and those of the checkpoint it resumed from.
        self.epochs_done = 0
        self._has_staged = False
        self._best_owed = False  # the pending best belongs to the epoch being committed
        self._trainer: L.Trainer | None = None
        self._restored: dict[str, Any] | None = None

    @property
    def state_key(self) -> str:
        return "tactile_compliance.EpochState"

    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        self._trainer = trainer

    def state_dict(self) -> dict[str, Any]:
        trainer = self._trainer
        assert trainer is not None
        return {
            "epochs_done": self.epochs_done,
            # Early stopping's decision of this epoch: a resumed run must not train on.
            "should_stop": bool(trainer.should_stop),
            "rng": _rng_states(),
        }

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self._restored = dict(state_dict)
        self.epochs_done = int(state_dict.get("epochs_done", 0))

    def on_fit_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        # Lightning has restored the checkpoint (callbacks before this hook on a single
        # device) and has not drawn a random number yet: the training loader's first
        # iterator (its base seed, and RandomSampler's seed for the first prefetched
        # batch) is created right after this hook, in FitLoop.setup_data, where an
        # uninterrupted run creates it at the next epoch's start. From here on the run
        # draws exactly the numbers the uninterrupted run drew after the saved epoch
        # (shuffling, dropout, loader worker seeds).
        restored, self._restored = self._restored, None
        if restored is None:
            return
        if restored.get("should_stop"):
            trainer.should_stop = True
        if "rng" in restored:
            _set_rng_states(restored["rng"])

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        # Lightning counts the epoch as completed only after this hook.
        self.epochs_done = trainer.current_epoch + 1
        with torch_write_errors(self.staged):
            trainer.save_checkpoint(self.staged)
        self._has_staged = True

    def on_train_epoch_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self.commit()

    def on_train_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self.commit()

    def on_exception(
        self, trainer: L.Trainer, pl_module: L.LightningModule, exception: BaseException
    ) -> None:
        # Interrupted inside commit() after the staged file became last.ckpt, before the
        # best checkpoint became best.pt: finish the commit (or leave it to the next
        # run's _find_resume_point if even that fails).
        if self._best_owed and not self.staged.exists():
            with contextlib.suppress(OSError):
                os.replace(self.pending_best, self.best_file)
        self._best_owed = False
        # An epoch that was not committed is redone by the next run: drop its files.
        self._has_staged = False
        for path in (self.staged, self.pending_best):
            with contextlib.suppress(OSError):
                path.unlink()

    def commit(self) -> None:
        """Make the staged epoch the resumable state (and its best weights best.pt)."""
        if not self._has_staged:
            return
        with open(self.staged, "rb") as handle:
            os.fsync(handle.fileno())
        # A pending best checkpoint now belongs to the staged epoch (it was written at
        # that epoch's validation, and no validation ran since).
        self._best_owed = self.pending_best.exists()
        if self.last.exists():
            _link_or_copy(self.last, self.previous)
        os.replace(self.staged, self.last)  # the commit point
        self._has_staged = False
        fsync_directory(self.directory)
        if self._best_owed:
            os.replace(self.pending_best, self.best_file)
            fsync_directory(self.best_file.parent)
        self._best_owed = False


def _link_or_copy(source: Path, target: Path) -> None:
    """``target`` becomes ``source``'s content while ``source`` stays (atomically)."""
    tmp = target.with_name(target.name + ".tmp")
    tmp.unlink(missing_ok=True)
    try:
        try:
            os.link(source, tmp)
        except OSError:  # no hard links on this file system: a copy
            shutil.copyfile(source, tmp)
        os.replace(tmp, target)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


class _EpochLog(Logger):
    """``logs/metrics.csv`` as Lightning's CSVLogger writes it (one line per logging call,
    columns sorted), but rewritten atomically on every call and continued on resume: it
    starts from the earlier epochs' lines instead of deleting them."""

    def __init__(self, run_dir: Path, rows: list[dict[str, Any]]) -> None:
        super().__init__()
        self.run_dir = run_dir
        self.path = run_dir / EPOCH_LOG
        self.rows = list(rows)

    @property
    def name(self) -> str:
        return ""

    @property
    def version(self) -> str:
        return "logs"

    @property
    def save_dir(self) -> str:
        return str(self.run_dir)

    @property
    def root_dir(self) -> str:
        return str(self.run_dir)

    @property
    def log_dir(self) -> str:
        return str(self.path.parent)

    def log_hyperparams(self, params: Any, *args: Any, **kwargs: Any) -> None:
        pass

    def log_metrics(self, metrics: dict[str, Any], step: int | None = None) -> None:
        row = {k: v.item() if isinstance(v, torch.Tensor) else v for k, v in metrics.items()}
        row["step"] = step if step is not None else len(self.rows)
        self.rows.append(row)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        columns = sorted(set().union(*self.rows))
        with atomic_file(self.path, "w") as handle:
            writer = csv.DictWriter(handle, fieldnames=columns, lineterminator="\n")
            writer.writeheader()
            writer.writerows(self.rows)


def _earlier_rows(path: Path, epochs_done: int) -> list[dict[str, Any]]:
    """The log lines of the epochs a resumed run keeps (epoch < ``epochs_done``)."""
    try:
        with open(path, newline="", encoding="utf-8") as handle:
            rows = list(csv.DictReader(handle))
    except (OSError, csv.Error, UnicodeDecodeError):
        return []
    kept = []
    for row in rows:
        try:
            epoch = int(float(row.get("epoch") or "nan"))
        except ValueError:
            continue  # a line cut short by a kill (older versions wrote in place)
        if epoch < epochs_done:
            kept.append({k: v for k, v in row.items() if k is not None and v not in ("", None)})
    return kept


@dataclass
class _ResumePoint:
    path: Path
    epochs_done: int
    best_epoch: int


def _inspect_checkpoint(path: Path) -> tuple[_ResumePoint | None, str]:
    """A readable Lightning checkpoint's resume point, or None and what is wrong with it."""
    try:
        with zipfile.ZipFile(path) as archive:  # torch.save writes a zip archive
            damaged = archive.testzip()  # reads every member and checks its CRC
        if damaged is not None:
            return None, f"{damaged} fails its checksum"
        checkpoint = torch.load(path, map_location="cpu", weights_only=True, mmap=True)
    except Exception as err:  # truncated, not a zip, unpickling failed: all unusable
        first_line = (str(err).strip().splitlines() or [""])[0]
        return None, f"{type(err).__name__}: {first_line}"[:300]
    if not isinstance(checkpoint, dict) or not {"state_dict", "loops", "epoch"} <= set(checkpoint):
        return None, "not a Lightning training checkpoint"
    callbacks = checkpoint.get("callbacks") or {}
    state = callbacks.get("tactile_compliance.EpochState") or {}
    best = callbacks.get("_BestCheckpoint") or {}
    return (
        _ResumePoint(
            path=path,
            # Older runs saved last.ckpt only at the end, within the last epoch.
            epochs_done=int(state.get("epochs_done", int(checkpoint["epoch"]) + 1)),
            best_epoch=int(best.get("best_epoch", -1)),
        ),
        "",
    )


def _pending_best_epoch(path: Path) -> int | None:
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True, mmap=True)
        return int(payload["metrics"]["best_epoch"])
    except Exception:  # unreadable: not committable
        return None


def _find_resume_point(run_dir: Path) -> _ResumePoint | None:
    """Where an interrupted run continues: ``last.ckpt``, else ``last.prev.ckpt``, else
    nowhere (a fresh start). An unreadable checkpoint is moved aside (``NAME.corrupt``,
    never deleted) with a warning naming it; a pending best checkpoint is committed when
    it belongs to the resumed state and dropped otherwise."""
    directory = run_dir / CHECKPOINT_DIR
    # Temp files of a killed process (all written by this module or save_checkpoint).
    for stale in (
        directory / (LAST_CHECKPOINT + ".tmp"),
        directory / (PREVIOUS_CHECKPOINT + ".tmp"),
        directory / (PENDING_BEST + ".tmp"),
        run_dir / (BEST_FILE + ".tmp"),
        run_dir / (RESULT_FILE + ".tmp"),
        run_dir / (EPOCH_LOG + ".tmp"),
    ):
        stale.unlink(missing_ok=True)
    found: _ResumePoint | None = None
    unreadable: list[tuple[Path, Path, str]] = []
    for path in (directory / LAST_CHECKPOINT, directory / PREVIOUS_CHECKPOINT):
        if not path.exists():
            continue
        found, problem = _inspect_checkpoint(path)
        if found is not None:
            break
        aside = path.with_name(path.name + ".corrupt")
        os.replace(path, aside)
        unreadable.append((path, aside, problem))
    for path, aside, problem in unreadable:
        outcome = (
            f"resuming from {found.path.name} (after epoch {found.epochs_done - 1})"
            if found is not None
            else "starting the run over"
        )
        warnings.warn(
            f"{path} is unreadable ({problem}); moved it to {aside.name} and {outcome}",
            RuntimeWarning,
            stacklevel=3,
        )
    pending = directory / PENDING_BEST
    if pending.exists():
        if found is not None and _pending_best_epoch(pending) == found.best_epoch:
            os.replace(pending, run_dir / BEST_FILE)  # killed between the two renames
        else:
            pending.unlink()  # an epoch that was not committed
    return found


def _accelerator(device: str) -> str:
    """Lightning's accelerator for ``training.device``; a missing GPU is a clear error."""
    if device == "auto":
        return "gpu" if torch.cuda.is_available() else "cpu"
    if device.startswith("cuda") and not torch.cuda.is_available():
        raise ValueError(
            f"training.device={device}, but torch sees no CUDA GPU (torch "
            f"{torch.__version__}); use training.device=auto or cpu"
        )
    return "gpu" if device.startswith("cuda") else device


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


def _loggers(run_dir: Path, earlier_rows: list[dict[str, Any]], tensorboard: Any) -> list[Any]:
    """The epoch log (logs/metrics.csv) always; TensorBoard on request."""
    return [_EpochLog(run_dir, earlier_rows), *([tensorboard] if tensorboard else [])]


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
    *,
    inputs: InputStrategy | str | None = None,
    seed: int = 0,
) -> tuple[pd.DataFrame, dict[str, Any]]:
    """Predictions on val and test, test metrics (overall, grouped, reference predictors).

    ``inputs`` (the run's input strategy) adds the scalar reference on that strategy's
    scalar inputs (none for Image), fitted with ``random_state=seed``; the references are
    fitted on the split's training rows (before balancing) and scored on its test rows.
    """
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
        inputs=inputs,
        seed=seed,
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

    Resumes an interrupted run from its last finished epoch (see the module docstring).

    Args:
        cfg: a validated experiment configuration.
        run_dir: where to write; default ``cfg.output_dir / run_name(cfg)``.
        progress: show progress bars.
        overwrite: retrain even when the run directory holds a finished result.
        verbose: show Lightning's start-up messages and its housekeeping warnings
            (:func:`lightning_messages`).

    Raises:
        DirectoryLockedError: another process is training in ``run_dir``.
        KeyboardInterrupt: Ctrl-C; re-running continues after the last finished epoch.
    """
    run_dir = Path(run_dir) if run_dir is not None else Path(cfg.output_dir) / run_name(cfg)
    if run_dir.is_dir():  # a run directory of ours, never a directory of someone's files
        claim_output_dir(run_dir, RUN_KIND, recognise=is_legacy_run_dir, option="--out")
    if not overwrite and (finished := _finished_result(run_dir)) is not None:
        return finished
    try:
        with lightning_messages(verbose):
            return _train(cfg, run_dir, progress=progress, overwrite=overwrite)
    finally:
        release_memory()


def _train(
    cfg: ExperimentConfig, run_dir: Path, *, progress: bool, overwrite: bool
) -> dict[str, Any]:
    started = time.perf_counter()
    with contextlib.ExitStack() as stack:
        # An existing run directory is locked before anything else, so a second process
        # fails at once; a new one only after the configuration and the store passed
        # every check, so that a failed check leaves no directory behind.
        locked = run_dir.is_dir()
        if locked:  # train() checked it is ours
            stack.enter_context(lock_directory(run_dir))
        _accelerator(cfg.training.device)  # a missing GPU fails before anything is written
        tensorboard = _tensorboard_logger(run_dir, cfg.training.tensorboard)
        L.seed_everything(cfg.seed, workers=True, verbose=False)
        model = build_model(cfg)
        data = prepare_data(cfg, getattr(model, "recommended_image_size", None))
        check_frame_size(cfg, model, data.image_size or data.store.image_size)
        if not locked:
            claim_output_dir(run_dir, RUN_KIND, option="--out")
            stack.enter_context(lock_directory(run_dir))
        # Another process may have finished this run while this one prepared its data.
        if not overwrite and (finished := _finished_result(run_dir)) is not None:
            return finished
        return _fit_and_evaluate(
            cfg, run_dir, model, data, tensorboard, started, progress, overwrite
        )
    raise AssertionError("unreachable")  # pragma: no cover - the with block returns


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
    resume = _find_resume_point(run_dir)
    earlier_rows = _earlier_rows(run_dir / EPOCH_LOG, resume.epochs_done) if resume else []

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
    # The weights file (e.g. from `pretrain`) the backbone started from: sha256 + provenance.
    weights_file = backbone_weights_file_record(model)
    if cfg.model.freeze_backbone:
        if cfg.augmentation.enabled:
            warnings.warn(
                "augmentation is ignored with freeze_backbone: features are cached from "
                "un-augmented frames (set augmentation.enabled=false to silence this)",
                stacklevel=3,
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

    def save_best(path: Path, extra: dict[str, Any]) -> None:
        save_checkpoint(
            path,
            model,
            constants=data.constants,
            image_size=data.image_size,
            config=config_dict,
            seed=cfg.seed,
            metrics=extra,
            backbone_weights_file=weights_file,
            frozen_backbone=frozen_backbone,
            store_image_size=data.store.image_size,
            analytical_estimator=data.store.analytical_estimator,
            sensor_units=data.store.sensor_units.to_dict(),
            store={"path": str(Path(data.store.path).resolve()), **data.store.header.to_dict()},
        )

    best = _BestCheckpoint(save_best, pending_best)
    epoch_state = _EpochState(checkpoint_dir, run_dir / BEST_FILE, pending_best)
    callbacks: list[Callback] = [best, epoch_state]
    if cfg.training.patience > 0:
        callbacks.append(EarlyStopping("val_nmse", patience=cfg.training.patience, mode="min"))
    accelerator = _accelerator(cfg.training.device)
    loggers = _loggers(run_dir, earlier_rows, tensorboard)
    trainer = L.Trainer(
        max_epochs=cfg.training.max_epochs,
        accelerator=accelerator,
        devices=1,
        precision=cfg.training.precision,
        deterministic=accelerator == "cpu",
        callbacks=callbacks,
        logger=loggers,
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
        inputs=cfg.inputs,
        seed=cfg.seed,
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
        "backbone_weights_sha256": weights_file["sha256"] if weights_file else None,
        "freeze_backbone": cfg.model.freeze_backbone,
        "image_size": list(data.image_size) if data.image_size else None,
        "n_train": len(data.train_ids),
        "n_val": len(data.val_ids),
        "n_test": len(data.split.test_ids),
        "best_epoch": best.best_epoch,
        "best_val_nmse": best.best,
        # A run resumed after early stopping trains nothing, and Lightning then leaves
        # current_epoch one short.
        "epochs_trained": max(trainer.current_epoch, epoch_state.epochs_done),
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
