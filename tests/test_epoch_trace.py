"""The kill tests' helpers (tests/epoch_trace.py) on hand-written traces, so a broken
helper shows up here in a second instead of as a kill test that never interrupts."""

from __future__ import annotations

import subprocess
import sys

import pytest

from epoch_trace import wait_until_midway


def _sleeper() -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-c", "import time; time.sleep(60)"],
        stderr=subprocess.PIPE,
        text=True,
    )


def test_wait_until_midway_returns_the_run_past_its_first_epoch(tmp_path):
    runs = {name: tmp_path / name for name in ("done", "first-epoch", "midway")}
    for run in runs.values():
        run.mkdir()
    (runs["done"] / "metrics.json").write_text("{}")
    trace = tmp_path / "trace"
    trace.write_text(
        f"1 0 {runs['done']}\n1 1 {runs['done']}\n2 0 {runs['first-epoch']}\n"
        f"3 0 {runs['midway']}\n3 1 {runs['midway']}\n"
    )
    proc = _sleeper()
    try:
        found = wait_until_midway(proc, trace, lambda: True, timeout_s=10, what="the command")
        assert found == runs["midway"]
        # Nothing finished yet: not midway in the kill tests' sense, so it waits.
        with pytest.raises(AssertionError, match="the command never got midway"):
            wait_until_midway(proc, trace, lambda: False, timeout_s=0.1, what="the command")
    finally:
        proc.kill()
        proc.wait()
    with pytest.raises(AssertionError, match="the command ended first"):
        wait_until_midway(proc, trace, lambda: True, timeout_s=10, what="the command")
