"""An interrupted ``train`` resumes after its last finished epoch and ends exactly as an
uninterrupted run; the run directory is locked; failures leave nothing half-written."""

from __future__ import annotations

import errno
import json
import os
import signal
import stat
import struct
import subprocess
import sys
import textwrap
import time
import zipfile
from pathlib import Path

import pandas as pd
import pytest
import torch
from typer.testing import CliRunner

from epoch_trace import committed_epochs, default_sigint
from tactile_compliance.cli import app
from tactile_compliance.data.store import StoreError
from tactile_compliance.outputs import (
    MARKER_NAME,
    DirectoryLockedError,
    claim_output_dir,
    exclusive_lock,
)
from tactile_compliance.runs.checkpoint import CHECKPOINT_FORMAT, save_checkpoint
from tactile_compliance.runs.layout import LOCK_FILE, RUN_KIND
from tactile_compliance.runs.results import ResultsStore
from tactile_compliance.runs.run_inputs import RunInputs
from tactile_compliance.training import module
from tactile_compliance.training.train import build_model, train
from toy_store import make_toy_store, tiny_run_config

TESTS_DIR = Path(__file__).resolve().parent

#: Top10NN end to end with augmentation on: shuffling, dropout (the fast CPU dropout draws
#: from torch's global generator) and the augmentation's own generator all draw random
#: numbers, and StepLR changes the learning rate every epoch. On the development machine
#: the best epoch is the last one (3), so the test metrics come from epochs trained after
#: the interruption.
RESUMED = [
    # Bit-identical resumption is a same-machine CPU fact (docs/training.md): on a GPU the
    # kernels are not deterministic, so even two uninterrupted runs differ in the last digits.
    "training.device=cpu",
    "training.batch_size=8",
    "data.image_size=[72,72]",
    "training.lr=1e-3",
    "training.gamma=0.8",
    "training.max_epochs=4",
    "training.patience=100",
    "augmentation.enabled=true",
]

#: Trains one run; appends "PID EPOCH" to TRACE whenever an epoch starts.
WORKER = textwrap.dedent(
    """
    import os, sys
    sys.path.insert(0, {tests!r})
    from toy_store import tiny_run_config
    from tactile_compliance.training import module
    from tactile_compliance.training.train import train

    store, run_dir, trace, *extra = sys.argv[1:]
    started = module.ComplianceModule.on_train_epoch_start

    def traced(self):
        with open(trace, "a") as handle:
            handle.write(f"{{os.getpid()}} {{self.current_epoch}}\\n")
        started(self)

    module.ComplianceModule.on_train_epoch_start = traced
    cfg = tiny_run_config(store, os.path.dirname(run_dir), "top10nn", extra)
    train(cfg, run_dir=run_dir, progress=False)
    """
).format(tests=str(TESTS_DIR))


@pytest.fixture(scope="module")
def small_store(tmp_path_factory):
    # Frames at the training size: no resizing, two batches per epoch.
    return make_toy_store(
        tmp_path_factory.mktemp("resume") / "store", n_objects=8, grasps=3, size=(72, 72)
    )


def _start(store, run_dir: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-c", WORKER, str(store.path), str(run_dir), f"{run_dir}.trace", *RESUMED],
        preexec_fn=default_sigint,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )


def _finish(proc: subprocess.Popen) -> None:
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err[-3000:]


def _trace(run_dir: Path) -> list[tuple[int, int]]:
    path = Path(f"{run_dir}.trace")
    if not path.exists():
        return []
    return [tuple(map(int, line.split())) for line in path.read_text().splitlines() if line]


@pytest.fixture(scope="module")
def uninterrupted(small_store, tmp_path_factory):
    """The reference: the same configuration run once without interruption (subprocess,
    like the interrupted runs, so that nothing of this process's state can differ)."""
    run_dir = tmp_path_factory.mktemp("uninterrupted") / "run"
    _finish(_start(small_store, run_dir))
    return run_dir


@pytest.mark.parametrize(
    "signum",
    [
        pytest.param(signal.SIGKILL, id="SIGKILL"),
        # 193 s at load 11-14 (SIGKILL: 100 s); Ctrl-C's layer runs by default in cheaper
        # tests (docs/testing.md, "Interruptions").
        pytest.param(signal.SIGINT, id="SIGINT", marks=pytest.mark.slow),
    ],
)
def test_interrupted_run_resumes_and_ends_as_if_uninterrupted(
    small_store, uninterrupted, tmp_path, signum
):
    run_dir, kill_at = tmp_path / "run", 2
    proc = _start(small_store, run_dir)
    deadline = time.monotonic() + 240
    # Epoch 2 has started, so epochs 0 and 1 are committed: interrupt it.
    while not any(epoch >= kill_at for _, epoch in _trace(run_dir)):
        assert proc.poll() is None, proc.communicate()[1][-3000:]
        assert time.monotonic() < deadline, "the run never reached epoch 2"
        time.sleep(0.02)
    proc.send_signal(signum)
    proc.communicate(timeout=120)
    assert proc.returncode != 0  # it was interrupted, not finished
    assert not (run_dir / "metrics.json").exists()
    done = committed_epochs(run_dir)
    assert done >= kill_at

    _finish(_start(small_store, run_dir))

    # (a) Nothing finished was trained again: the re-run started right after the last
    # committed epoch, and the epoch log holds every epoch once.
    trace = _trace(run_dir)
    first_pid = trace[0][0]
    assert len({pid for pid, _ in trace}) == 2
    assert [epoch for pid, epoch in trace if pid != first_pid] == list(range(done, 4))
    log = pd.read_csv(run_dir / "logs" / "metrics.csv")
    for column in ("val_nmse", "train_loss"):
        assert log.dropna(subset=[column])["epoch"].astype(int).tolist() == [0, 1, 2, 3]

    # (b) Exactly the uninterrupted run's result, epoch log and best checkpoint.
    reference = json.loads((uninterrupted / "metrics.json").read_text())
    resumed = json.loads((run_dir / "metrics.json").read_text())
    for key in ("test", "val", "reference", "best_epoch", "best_val_nmse", "epochs_trained"):
        assert resumed[key] == reference[key], key
    assert log.equals(pd.read_csv(uninterrupted / "logs" / "metrics.csv"))
    best, best_reference = (
        torch.load(d / "best.pt", weights_only=True) for d in (run_dir, uninterrupted)
    )
    assert best["metrics"] == best_reference["metrics"]
    assert best["metrics"]["best_epoch"] == reference["best_epoch"]
    for key, value in best_reference["state_dict"].items():
        assert torch.equal(best["state_dict"][key], value), key
    assert not list(run_dir.rglob("*.tmp"))


@pytest.fixture
def toy_store(tmp_path_factory):
    return make_toy_store(tmp_path_factory.mktemp("toy") / "store", n_objects=8, grasps=2)


def _quick(store_path, out, extra=()):
    return tiny_run_config(
        store_path,
        out,
        "top10nn",
        # CPU: resumed runs are compared bit for bit (see RESUMED).
        [
            "training.device=cpu",
            "data.image_size=[72,72]",
            "training.lr=1e-3",
            "training.max_epochs=3",
            *extra,
        ],
    )


def _trained_epochs(monkeypatch) -> list[int]:
    """The epochs this process starts training from now on, in order."""
    epochs: list[int] = []
    started = module.ComplianceModule.on_train_epoch_start

    def traced(self):
        epochs.append(self.current_epoch)
        started(self)

    monkeypatch.setattr(module.ComplianceModule, "on_train_epoch_start", traced)
    return epochs


def _flip_a_byte_of_the_largest_tensor(path: Path) -> None:
    """Damage a stored tensor without touching the zip structure: torch.load reads the
    file without complaint (it checks no CRC), only the members' checksums tell."""
    with zipfile.ZipFile(path) as archive:
        info = max(archive.infolist(), key=lambda i: i.file_size)
    raw = bytearray(path.read_bytes())
    name_length, extra_length = struct.unpack_from("<HH", raw, info.header_offset + 26)
    start = info.header_offset + 30 + name_length + extra_length  # the member's bytes
    raw[start + info.file_size // 2] ^= 0xFF
    path.write_bytes(bytes(raw))
    torch.load(path, weights_only=True)  # still loads


def test_unreadable_checkpoint_falls_back_to_the_previous_one_then_to_a_fresh_start(
    toy_store, tmp_path, monkeypatch
):
    run_dir = tmp_path / "run"
    cfg = _quick(toy_store.path, tmp_path)
    first = train(cfg, run_dir=run_dir, progress=False)
    checkpoints = run_dir / "checkpoints"
    assert {p.name for p in checkpoints.iterdir()} == {"last.ckpt", "last.prev.ckpt"}
    epochs = _trained_epochs(monkeypatch)
    last, previous = checkpoints / "last.ckpt", checkpoints / "last.prev.ckpt"

    # Killed while an older version wrote last.ckpt in place: it is cut short. Or a bit
    # flipped on the disk. Either way last.prev.ckpt (epochs 0 and 1) takes over and only
    # the last epoch is trained again.
    damages = {
        "truncated": lambda path: path.write_bytes(path.read_bytes()[: path.stat().st_size // 2]),
        "bit flip": _flip_a_byte_of_the_largest_tensor,
    }
    for damage, reason in (("truncated", "BadZipFile"), ("bit flip", "fails its checksum")):
        (run_dir / "metrics.json").unlink()
        (checkpoints / "last.ckpt.corrupt").unlink(missing_ok=True)
        damages[damage](last)
        damaged = last.read_bytes()
        epochs.clear()
        with pytest.warns(
            RuntimeWarning, match=rf"last\.ckpt is unreadable \(.*{reason}.*resuming from last"
        ):
            again = train(cfg, run_dir=run_dir, progress=False)
        assert epochs == [2], damage
        for key in ("test", "best_epoch", "best_val_nmse", "epochs_trained"):
            assert again[key] == first[key], (damage, key)
        # Set aside as it was, never deleted.
        assert (checkpoints / "last.ckpt.corrupt").read_bytes() == damaged, damage
        log = pd.read_csv(run_dir / "logs" / "metrics.csv").dropna(subset=["val_nmse"])
        assert log["epoch"].astype(int).tolist() == [0, 1, 2]

    # Both unreadable: the run starts over (and still ends the same way).
    (run_dir / "metrics.json").unlink()
    for path in (last, previous):
        path.write_bytes(b"not a checkpoint")
    epochs.clear()
    with pytest.warns(RuntimeWarning, match="starting the run over"):
        fresh = train(cfg, run_dir=run_dir, progress=False)
    assert epochs == [0, 1, 2]
    assert fresh["test"] == first["test"] and fresh["epochs_trained"] == 3
    assert (checkpoints / "last.prev.ckpt.corrupt").read_bytes() == b"not a checkpoint"
    assert (checkpoints / "last.ckpt.corrupt").read_bytes() == b"not a checkpoint"


def test_a_run_that_stopped_early_does_not_train_on_when_resumed(toy_store, tmp_path):
    run_dir = tmp_path / "run"
    extra = ["training.lr=3e-2", "training.max_epochs=12", "training.patience=1"]
    cfg = _quick(toy_store.path, tmp_path, extra)
    first = train(cfg, run_dir=run_dir, progress=False)
    assert first["epochs_trained"] < 12  # early stopping ended it
    # Killed while evaluating: the re-run restores early stopping's decision.
    (run_dir / "metrics.json").unlink()
    again = train(cfg, run_dir=run_dir, progress=False)
    for key in ("test", "best_epoch", "best_val_nmse", "epochs_trained"):
        assert again[key] == first[key], key
    log = pd.read_csv(run_dir / "logs" / "metrics.csv").dropna(subset=["val_nmse"])
    assert log["epoch"].astype(int).tolist() == list(range(first["epochs_trained"]))


_HOLDER = textwrap.dedent(
    """
    import sys, time
    from pathlib import Path
    from tactile_compliance.outputs import exclusive_lock
    with exclusive_lock(Path(sys.argv[1]) / ".lock", wait=False):
        print("locked", flush=True)
        time.sleep(120)
    """
)


def test_a_locked_run_directory_fails_at_once_and_a_dead_holders_lock_is_taken_over(
    toy_store, tmp_path
):
    run_dir = claim_output_dir(tmp_path / "run", RUN_KIND)  # as train() makes it
    holder = subprocess.Popen(
        [sys.executable, "-c", _HOLDER, str(run_dir)], stdout=subprocess.PIPE, text=True
    )
    try:
        assert holder.stdout.readline().strip() == "locked"
        cfg = _quick(toy_store.path, tmp_path, ["training.max_epochs=1"])
        started = time.monotonic()
        with pytest.raises(DirectoryLockedError) as caught:
            train(cfg, run_dir=run_dir, progress=False)
        assert time.monotonic() - started < 5  # before building the model or the data
        message = str(caught.value)
        assert "\n" not in message
        assert str(run_dir / ".lock") in message and f"pid {holder.pid} " in message
        # The command line prints it as one line.
        result = CliRunner().invoke(
            app,
            # A frame size the model takes: only the lock stops it.
            [
                "train",
                "--set",
                f"data.store={toy_store.path}",
                "--size",
                "72x72",
                "--out",
                str(run_dir),
            ],
        )
        assert result.exit_code == 2 and f"pid {holder.pid} " in result.output
        assert result.output.strip().count("\n") == 0, result.output
        # Nothing written besides the marker and the holder's lock.
        assert sorted(p.name for p in run_dir.iterdir()) == [".lock", MARKER_NAME]
    finally:
        holder.kill()  # SIGKILL: its lock file stays behind with its record
        holder.wait()
    assert f"pid {holder.pid} " in (run_dir / ".lock").read_text()
    result = train(cfg, run_dir=run_dir, progress=False)
    assert result["epochs_trained"] == 1
    assert (run_dir / ".lock").read_text() == ""  # released


def test_a_lock_that_does_not_wait_in_one_process(tmp_path):
    with exclusive_lock(tmp_path / LOCK_FILE, wait=False) as path:
        assert path.read_text().startswith(f"pid {os.getpid()} on ")
        second = exclusive_lock(tmp_path / LOCK_FILE, "run directory", wait=False)
        with pytest.raises(DirectoryLockedError, match=f"held by pid {os.getpid()} "):
            second.__enter__()
    assert (tmp_path / LOCK_FILE).read_text() == ""  # released: names nobody
    with exclusive_lock(tmp_path / LOCK_FILE, wait=False):  # free again
        pass


def test_a_failed_check_creates_no_run_directory(toy_store, tmp_path):
    out = tmp_path / "out"
    missing = _quick(tmp_path / "no-store", out)
    with pytest.raises(StoreError):
        train(missing, progress=False)
    # A subset the store does not have fails the check against the store's samples.
    bad = _quick(toy_store.path, out, ["split.subset=Hex"])
    with pytest.raises(ValueError, match="Hex"):
        train(bad, progress=False)
    with pytest.raises(ValueError, match="Hex"):
        train(bad, run_dir=out / "explicit", progress=False)
    assert not out.exists()


def _full_disk(monkeypatch, fails) -> None:
    """torch.save writes a few bytes, then fails like a full disk, for the payloads for
    which ``fails(payload)`` is true."""
    real_save = torch.save

    def save(obj, f, *args, **kwargs):
        if not fails(obj):
            return real_save(obj, f, *args, **kwargs)
        if hasattr(f, "write"):
            f.write(b"\0" * 4096)
        else:
            Path(f).write_bytes(b"\0" * 4096)
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(torch, "save", save)


def _is_best(payload) -> bool:
    return isinstance(payload, dict) and payload.get("format") == CHECKPOINT_FORMAT


def test_full_disk_while_saving_a_checkpoint_leaves_no_temp_file(tmp_path, monkeypatch):
    cfg = tiny_run_config(tmp_path / "no-store", tmp_path, "top10nn")
    model = build_model(cfg)
    target = tmp_path / "best.pt"
    target.write_bytes(b"the previous best")
    _full_disk(monkeypatch, _is_best)
    with pytest.raises(OSError, match="No space left"):
        save_checkpoint(
            target, model,
            run_inputs=RunInputs((72, 72), (32, 32), cfg.normalisation_constants(), cfg.inputs),
            config={}, seed=0,
        )  # fmt: skip
    assert sorted(p.name for p in tmp_path.iterdir()) == ["best.pt"]
    assert target.read_bytes() == b"the previous best"


def test_full_disk_while_saving_best_pt_during_training_leaves_no_temp_file(
    toy_store, tmp_path, monkeypatch
):
    run_dir = tmp_path / "run"
    _full_disk(monkeypatch, _is_best)
    with pytest.raises(OSError, match="No space left"):
        train(_quick(toy_store.path, tmp_path), run_dir=run_dir, progress=False)
    assert not list(run_dir.rglob("*.tmp"))
    assert not (run_dir / "checkpoints" / "best.pending.pt").exists()


def test_full_disk_while_saving_the_training_state_keeps_the_previous_epoch(
    toy_store, tmp_path, monkeypatch
):
    run_dir = tmp_path / "run"
    cfg = _quick(toy_store.path, tmp_path)
    saves = []

    def second_training_state(payload) -> bool:  # Lightning's checkpoint after epoch 1
        if isinstance(payload, dict) and "loops" in payload:
            saves.append(payload["epoch"])
            return len(saves) == 2
        return False

    _full_disk(monkeypatch, second_training_state)
    with pytest.raises(OSError, match="No space left"):
        train(cfg, run_dir=run_dir, progress=False)
    assert not list(run_dir.rglob("*.tmp"))
    assert committed_epochs(run_dir) == 1  # epoch 0's state, intact
    monkeypatch.undo()  # space again: the re-run resumes with epoch 1
    result = train(cfg, run_dir=run_dir, progress=False)
    assert result["epochs_trained"] == 3
    log = pd.read_csv(run_dir / "logs" / "metrics.csv").dropna(subset=["val_nmse"])
    assert log["epoch"].astype(int).tolist() == [0, 1, 2]


def test_result_rows_follow_the_umask(tmp_path):
    store = ResultsStore(tmp_path / "results")
    previous = os.umask(0o022)
    try:
        for umask, expected in ((0o022, 0o644), (0o002, 0o664), (0o077, 0o600)):
            os.umask(umask)
            path = store.record({"key": f"k{umask:o}", "status": "complete"})
            assert stat.S_IMODE(path.stat().st_mode) == expected, oct(umask)
    finally:
        os.umask(previous)
    assert sorted(p.name for p in (tmp_path / "results" / "rows").iterdir()) == [
        "k2.json",
        "k22.json",
        "k77.json",
    ]


def test_a_best_checkpoint_pending_for_the_resumed_epoch_becomes_best_pt(tmp_path):
    """Killed between committing last.ckpt and renaming its best epoch's weights."""
    from tactile_compliance.runs.layout import BEST_FILE, CHECKPOINT_DIR, LAST_CHECKPOINT
    from tactile_compliance.training.resume import (
        BEST_STATE_KEY,
        EPOCH_STATE_KEY,
        PENDING_BEST,
        find_resume_point,
    )

    directory = tmp_path / CHECKPOINT_DIR
    directory.mkdir()
    callbacks = {EPOCH_STATE_KEY: {"epochs_done": 3}, BEST_STATE_KEY: {"best_epoch": 2}}
    state = {"state_dict": {}, "loops": {}, "epoch": 2, "callbacks": callbacks}
    torch.save(state, directory / LAST_CHECKPOINT)
    torch.save({"metrics": {"best_epoch": 2}}, directory / PENDING_BEST)
    found = find_resume_point(tmp_path)
    assert found is not None and (found.epochs_done, found.best_epoch) == (3, 2)
    assert (tmp_path / BEST_FILE).is_file() and not (directory / PENDING_BEST).exists()


def test_a_pre_release_training_checkpoint_is_set_aside_naming_the_version(tmp_path):
    from tactile_compliance.runs.layout import CHECKPOINT_DIR, LAST_CHECKPOINT
    from tactile_compliance.training.resume import find_resume_point

    last = tmp_path / CHECKPOINT_DIR / LAST_CHECKPOINT
    last.parent.mkdir()
    # A Lightning checkpoint without this package's epoch state (pre-release runs).
    torch.save({"state_dict": {}, "loops": {}, "epoch": 3, "callbacks": {}}, last)
    with pytest.warns(RuntimeWarning, match=r"version before 0\.1\.0.*starting the run over"):
        assert find_resume_point(tmp_path) is None
    assert not last.exists() and last.with_name(LAST_CHECKPOINT + ".corrupt").is_file()


def test_the_epoch_log_reader_skips_lines_without_an_epoch(tmp_path: Path) -> None:
    from tactile_compliance.runs.layout import read_epoch_log
    from tactile_compliance.training.resume import read_earlier_rows

    log = tmp_path / "metrics.csv"
    # Train and validation lines of two epochs, a line without an epoch and one cut short.
    lines = ["epoch,train_loss,val_nmse", "0,0.5,", "0,,0.2", ",0.4,", "1,0.3,", "1.0,,0.1", "2,0."]
    log.write_text("\n".join(lines), encoding="utf-8")
    rows = read_epoch_log(log)
    assert [epoch for epoch, _ in rows] == [0, 0, 1, 1, 2]
    assert rows[2][1]["train_loss"] == "0.3"
    # A resumed run after one epoch keeps epoch 0's lines, without their empty cells.
    assert read_earlier_rows(log, 1) == [
        {"epoch": "0", "train_loss": "0.5"},
        {"epoch": "0", "val_nmse": "0.2"},
    ]
    assert read_earlier_rows(tmp_path / "missing.csv", 1) == []


def test_a_resumed_run_says_so_in_one_line_and_lists_its_resumes_in_metrics_json(
    toy_store, tmp_path, capsys
):
    run_dir = tmp_path / "run"
    cfg = _quick(toy_store.path, tmp_path)  # 3 epochs, quiet (verbose=False)
    first = train(cfg, run_dir=run_dir, progress=False)
    assert first["resumed_from_epoch"] == []
    assert "resuming" not in capsys.readouterr().err
    # Killed in its last epoch: last.ckpt holds epochs 0 and 1 (what last.prev.ckpt holds).
    checkpoints = run_dir / "checkpoints"
    (run_dir / "metrics.json").unlink()
    os.replace(checkpoints / "last.prev.ckpt", checkpoints / "last.ckpt")
    again = train(cfg, run_dir=run_dir, progress=False)
    assert f"resuming {run_dir} after epoch 2 of 3" in capsys.readouterr().err.splitlines()
    assert again["resumed_from_epoch"] == [2]
    assert again["test"] == first["test"]
    # Killed again, after the last epoch and before metrics.json: both resumes are listed.
    (run_dir / "metrics.json").unlink()
    third = train(cfg, run_dir=run_dir, progress=False)
    assert f"resuming {run_dir} after epoch 3 of 3" in capsys.readouterr().err.splitlines()
    assert third["resumed_from_epoch"] == [2, 3]
    assert json.loads((run_dir / "metrics.json").read_text())["resumed_from_epoch"] == [2, 3]
