"""`train` is quiet by default: Lightning's start-up messages (GPU available, the
litlogger tip, batch limits, "`weights_only` was not set") and its deprecation warnings
show only with `--verbose`; the run's own result line always shows. `--keep-checkpoints
best` keeps best.pt only; `--size HxW` and `--json` work as on the other commands."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from toy_store import make_toy_store

REPO = Path(__file__).resolve().parents[1]
NOISE = ("GPU available", "litlogger", "weights_only", "LeafSpec", "limit_train_batches")


def _train(store: Path, runs: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    # A subprocess: Lightning's log handlers and warnings write to the real stderr.
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(REPO / "src"), *sys.path]),
        "OMP_NUM_THREADS": "1",
    }
    args = [
        *("--set", f"data.store={store}", "--set", f"output_dir={runs}"),
        *("--set", "training.max_epochs=1"),
        *("--set", "training.batch_size=16", "--set", "augmentation.enabled=false"),
    ]
    return subprocess.run(
        [sys.executable, "-m", "tactile_compliance", "train", *args, *extra],
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
        check=False,
    )


def _run_dir(stdout: str) -> Path:
    return Path(stdout.split("Run directory: ", 1)[1].strip())


def test_train_is_quiet_by_default_and_keeps_what_it_is_told(tmp_path: Path) -> None:
    store = make_toy_store(tmp_path / "store", n_objects=6, grasps=2, size=(72, 72)).path
    quiet = _train(store, tmp_path / "runs", "--size", "72x72")
    assert quiet.returncode == 0, quiet.stderr
    assert "best epoch" in quiet.stdout and "Run directory" in quiet.stdout
    assert quiet.stderr.strip() == "", quiet.stderr
    run_dir = _run_dir(quiet.stdout)
    assert (run_dir / "best.pt").is_file() and (run_dir / "checkpoints" / "last.ckpt").is_file()

    verbose = _train(
        store,
        tmp_path / "runs",
        *("--set", "data.image_size=[72,72]"),  # the same run as --size 72x72
        *("--overwrite", "--verbose", "--keep-checkpoints", "best", "--json"),
    )
    assert verbose.returncode == 0, verbose.stderr
    shown = [text for text in NOISE if text in verbose.stderr]
    assert {"GPU available", "litlogger", "weights_only"} <= set(shown), verbose.stderr
    result = json.loads(verbose.stdout)  # --json: the run's result, nothing else
    assert Path(result["run_dir"]) == run_dir and result["image_size"] == [72, 72]
    assert (run_dir / "best.pt").is_file() and not (run_dir / "checkpoints").exists()
