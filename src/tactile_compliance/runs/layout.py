"""A run directory's names, and how its files are written and who may write them.

Training writes these files, evaluation and inference read them, and grids and tuning
name their runs with :func:`run_name`. The full layout of a run directory is described
in ``training/train.py``.

Two generic helpers live here because every writer of a run directory needs them:

* :func:`atomic_file`: a file appears complete or not at all (temp file, fsync, rename),
  and the temp file is removed when writing fails (a full disk, Ctrl-C);
* :func:`lock_directory`: one process at a time per directory; a second one fails at once
  with :class:`DirectoryLockedError` naming the lock file and its holder. The lock is an
  ``fcntl.flock``, which the kernel releases when its process dies, so a lock left by a
  killed process is simply taken over.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import re
import socket
from collections.abc import Iterator
from datetime import datetime
from pathlib import Path

from tactile_compliance.config import ExperimentConfig, config_to_dict
from tactile_compliance.data.splits import is_split_file
from tactile_compliance.data.store import SAMPLE_COLUMNS
from tactile_compliance.outputs import process_alive

try:
    import fcntl
except ImportError:  # Windows: no flock; the lock falls back to the holder's PID
    fcntl = None  # type: ignore[assignment]

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


# ============================================================================== the lock


class DirectoryLockedError(OSError):
    """Another process holds the directory's lock (see :func:`lock_directory`)."""


def _holder_record() -> str:
    since = datetime.now().astimezone().isoformat(timespec="seconds")
    return f"pid {os.getpid()} on {socket.gethostname()} since {since}"


def _held_by_other_process(record: str) -> bool:
    """For file systems without ``flock``: whether ``record`` names a live other process."""
    match = re.match(r"pid (\d+) on (\S+)", record)
    if match is None:
        return False
    pid, host = int(match.group(1)), match.group(2)
    if host != socket.gethostname():
        return True  # cannot tell from here: treat as held (the message says what to do)
    return pid != os.getpid() and process_alive(pid)


@contextlib.contextmanager
def lock_directory(
    directory: str | Path, *, name: str = LOCK_FILE, what: str = "run directory"
) -> Iterator[Path]:
    """Hold an exclusive lock on ``directory`` (which must exist) for the block.

    The lock is an ``fcntl.flock`` on ``DIRECTORY/NAME``, taken without waiting; the file
    records the holder (``pid PID on HOST since TIME``). The kernel releases the lock when
    its process ends, however it ends, so a lock file left by a dead process is taken over.
    The file itself is never deleted (deleting it while another process opens it would let
    two processes lock two different files). Where ``flock`` is not available (Windows, a
    file system that refuses it) the recorded PID decides: a live process on this host, or
    any process on another host, holds the lock.

    Raises:
        DirectoryLockedError: another process holds the lock (one line naming the lock
            file and the holder).
    """
    directory = Path(directory)
    path = directory / name
    handle = open(path, "a+", encoding="utf-8")  # noqa: SIM115 (held for the whole block)
    try:
        locked = False
        if fcntl is not None:
            try:
                fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
                locked = True
            except OSError as err:
                if err.errno not in (errno.ENOSYS, errno.EOPNOTSUPP, errno.ENOLCK):
                    handle.seek(0)
                    holder = handle.read().strip() or "another process"
                    raise DirectoryLockedError(
                        f"{directory} is in use: its lock {path} is held by {holder}; wait "
                        f"for that process to finish or use another {what}"
                    ) from None
        if not locked:  # no flock here: fall back to the recorded PID
            handle.seek(0)
            holder = handle.read().strip()
            if holder and _held_by_other_process(holder):
                raise DirectoryLockedError(
                    f"{directory} is in use: its lock {path} is held by {holder}; wait for "
                    f"that process to finish or use another {what} (delete the lock file if "
                    f"that process is gone)"
                )
        handle.seek(0)
        handle.truncate()
        handle.write(_holder_record() + "\n")
        handle.flush()
        try:
            yield path
        finally:
            # Released: an empty file names nobody (a killed holder leaves its record).
            with contextlib.suppress(OSError):
                handle.seek(0)
                handle.truncate()
                handle.flush()
    finally:
        handle.close()


#: The kind of a run directory in its ``outputs`` marker.
RUN_KIND = "run"

#: What a finished run keeps (``--keep-checkpoints``): ``best.pt`` and ``checkpoints/``
#: (all), ``best.pt`` only (best), nothing of either (none: the metrics and predictions).
KEEP_CHECKPOINTS = ("all", "best", "none")


def prune_checkpoints(run_dir: str | Path, keep: str) -> None:
    """Delete the checkpoints of a finished run that ``keep`` does not keep.

    ``checkpoints/last.ckpt`` only serves to resume an interrupted run, and with a
    fine-tuned VGG16 backbone it weighs over half a gigabyte (more with optimizer state; a
    frozen one is left out): a finished run does not need it. ``best.pt`` is what
    ``evaluate`` and inference load. Deletes only these files of the run's own layout.
    """
    if keep not in KEEP_CHECKPOINTS:
        raise ValueError(
            f"keep_checkpoints must be one of {', '.join(KEEP_CHECKPOINTS)}, got {keep!r}"
        )
    if keep == "all":
        return
    import shutil

    shutil.rmtree(Path(run_dir) / CHECKPOINT_DIR, ignore_errors=True)
    if keep == "none":
        (Path(run_dir) / BEST_FILE).unlink(missing_ok=True)


def is_legacy_run_dir(path: Path) -> bool:
    """Whether ``path`` is a run directory written before markers existed: it holds a
    ``split.json`` that is a saved split (what ``train`` writes first)."""
    split = path / "split.json"
    try:
        return split.is_file() and is_split_file(split)
    except (OSError, ValueError):
        return False
