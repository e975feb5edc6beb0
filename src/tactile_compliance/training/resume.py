"""The resume engine of :func:`~tactile_compliance.training.train.train`.

Epoch-end checkpoints and their commit, the best epoch's weights, the epoch log across
restarts and where a re-run starts. See docs/training.md, "Interrupted runs resume exactly".
"""

from __future__ import annotations

import contextlib
import csv
import os
import random
import shutil
import warnings
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
import torch
from lightning.pytorch.callbacks import Callback, Checkpoint
from lightning.pytorch.loggers import Logger

from tactile_compliance.data.safe_pickle import torch_file_problem
from tactile_compliance.outputs import atomic_file, fsync_directory
from tactile_compliance.runs.checkpoint import torch_write_errors
from tactile_compliance.runs.layout import (
    BEST_FILE,
    CHECKPOINT_DIR,
    EPOCH_LOG,
    LAST_CHECKPOINT,
    PREVIOUS_CHECKPOINT,
    RESULT_FILE,
    read_epoch_log,
)

__all__ = [
    "BEST_STATE_KEY",
    "EPOCH_STATE_KEY",
    "PENDING_BEST",
    "BestCheckpoint",
    "EpochLog",
    "EpochState",
    "ResumePoint",
    "find_resume_point",
    "read_earlier_rows",
]


# ======================================================================= resumable state
#
# An epoch's checkpoint is staged at its end (on_train_epoch_end) and committed once
# Lightning has finished the epoch's bookkeeping (scheduler step, the epoch's log rows):
# at the next epoch's start or at the end of training.

PENDING_BEST = "best.pending.pt"
_STAGED_SUFFIX = ".tmp"
#: The callbacks' keys in Lightning's checkpoint (what a resumed run reads back).
BEST_STATE_KEY = "_BestCheckpoint"
EPOCH_STATE_KEY = "tactile_compliance.EpochState"


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


class BestCheckpoint(Callback):
    """Tracks the best validation N-MSE and writes that epoch's self-describing checkpoint.

    The checkpoint goes to ``checkpoints/best.pending.pt``; :class:`EpochState` turns it
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

    @property
    def state_key(self) -> str:
        # Lightning's default is the class name: keep the key written before the move here.
        return BEST_STATE_KEY

    def state_dict(self) -> dict[str, Any]:
        return {"best": self.best, "best_epoch": self.best_epoch}

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self.best = float(state_dict["best"])
        self.best_epoch = int(state_dict["best_epoch"])


class EpochState(Checkpoint):
    """Writes Lightning's full checkpoint at the end of every epoch and commits it (above).

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
        #: The epoch (0-based) each resume of this run started from, oldest first; kept in
        #: the checkpoint, so a run resumed twice lists both (``metrics.json``).
        self.resumed_from_epoch: list[int] = []
        self._has_staged = False
        self._best_owed = False  # the pending best belongs to the epoch being committed
        self._trainer: L.Trainer | None = None
        self._restored: dict[str, Any] | None = None

    @property
    def state_key(self) -> str:
        return EPOCH_STATE_KEY

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
            "resumed_from_epoch": list(self.resumed_from_epoch),
        }

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        # Lightning calls this only when a run resumes from a checkpoint: one more resume.
        self._restored = dict(state_dict)
        self.epochs_done = int(state_dict.get("epochs_done", 0))
        earlier = [int(epoch) for epoch in state_dict.get("resumed_from_epoch", [])]
        self.resumed_from_epoch = [*earlier, self.epochs_done]

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
        # run's find_resume_point if even that fails).
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


class EpochLog(Logger):
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


def read_earlier_rows(path: Path, epochs_done: int) -> list[dict[str, Any]]:
    """The log lines of the epochs a resumed run keeps (epoch < ``epochs_done``)."""
    try:
        rows = read_epoch_log(path)
    except (OSError, csv.Error, UnicodeDecodeError):
        return []
    return [
        {k: v for k, v in row.items() if k is not None and v not in ("", None)}
        for epoch, row in rows
        if epoch < epochs_done
    ]


@dataclass
class ResumePoint:
    """A readable epoch-end checkpoint: its file, the epochs it holds, its best epoch."""

    path: Path
    epochs_done: int
    best_epoch: int


def _inspect_checkpoint(path: Path) -> tuple[ResumePoint | None, str]:
    """A readable Lightning checkpoint's resume point, or None and what is wrong with it."""
    try:
        with zipfile.ZipFile(path) as archive:  # torch.save writes a zip archive
            damaged = archive.testzip()  # reads every member and checks its CRC
        if damaged is not None:
            return None, f"{damaged} fails its checksum"
        checkpoint = torch.load(path, map_location="cpu", weights_only=True, mmap=True)
    except Exception as err:  # truncated, not a zip, unpickling failed: all unusable
        if "weights_only" in str(err) or "WeightsUnpickler" in str(err):
            # Our own line: torch's message advises loading with weights_only=False.
            return None, torch_file_problem(path, err)[:300]
        first_line = (str(err).strip().splitlines() or [""])[0]
        return None, f"{type(err).__name__}: {first_line}"[:300]
    if not isinstance(checkpoint, dict) or not {"state_dict", "loops", "epoch"} <= set(checkpoint):
        return None, "not a Lightning training checkpoint"
    callbacks = checkpoint.get("callbacks") or {}
    state = callbacks.get(EPOCH_STATE_KEY) or {}
    best = callbacks.get(BEST_STATE_KEY) or {}
    if "epochs_done" not in state:
        # Pre-release runs saved last.ckpt without the epoch state: it cannot resume exactly.
        return None, "no epoch state (a training checkpoint of a version before 0.1.0)"
    return ResumePoint(path, int(state["epochs_done"]), int(best.get("best_epoch", -1))), ""


def _pending_best_epoch(path: Path) -> int | None:
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True, mmap=True)
        return int(payload["metrics"]["best_epoch"])
    except Exception:  # unreadable: not committable
        return None


def find_resume_point(run_dir: Path) -> ResumePoint | None:
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
    found: ResumePoint | None = None
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
