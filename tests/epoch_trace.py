"""An epoch log of every training process a test starts, Dask workers included.

The kill tests interrupt real command-line processes (``experiment`` with its Dask
workers, ``tune`` with its trials) and must know afterwards which process trained which
epoch of which run. Nothing in the package writes that, and monkeypatching works only in
the test's own process. So :func:`traced_env` writes a ``sitecustomize.py`` into a
directory of the test and puts it first on ``PYTHONPATH``: every Python process started
with that environment (the command, the Dask nanny's spawned workers) imports it at start.
It patches ``ComplianceModule.on_train_epoch_start`` once the training module is imported
(not before, so a process that never trains never imports torch for it) to append
``PID EPOCH RUN_DIR`` to the trace file. Lightning calls the callbacks' hook first, so an
epoch is traced after the previous one was committed to ``last.ckpt``.
"""

from __future__ import annotations

import os
import signal
import subprocess
import textwrap
import time
from collections.abc import Callable
from pathlib import Path

TRACE_VARIABLE = "TACTILE_TEST_EPOCH_TRACE"

_SITECUSTOMIZE = textwrap.dedent(
    """
    import importlib.abc
    import importlib.machinery
    import os
    import sys

    _TARGET = "tactile_compliance.training.module"


    def _patch(module):
        started = module.ComplianceModule.on_train_epoch_start

        def traced(self):
            run_dir = self.trainer.logger.save_dir  # train()'s epoch log lives in RUN_DIR
            with open(os.environ[{variable!r}], "a") as handle:
                handle.write(f"{{os.getpid()}} {{self.current_epoch}} {{run_dir}}\\n")
            started(self)

        module.ComplianceModule.on_train_epoch_start = traced


    class _Finder(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path, target=None):
            if name != _TARGET:
                return None
            spec = importlib.machinery.PathFinder.find_spec(name, path)
            if spec is None or spec.loader is None:
                return spec
            run = spec.loader.exec_module

            def exec_module(module):
                run(module)
                _patch(module)

            spec.loader.exec_module = exec_module
            return spec


    if os.environ.get({variable!r}):
        sys.meta_path.insert(0, _Finder())
    """
).format(variable=TRACE_VARIABLE)


def traced_env(directory: Path, trace: Path) -> dict[str, str]:
    """The environment for a subprocess whose training epochs are appended to ``trace``."""
    directory.mkdir(parents=True, exist_ok=True)
    (directory / "sitecustomize.py").write_text(_SITECUSTOMIZE)
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(directory), env.get("PYTHONPATH", "")) if p)
    env[TRACE_VARIABLE] = str(trace)
    # The traced runs are compared bit for bit with uninterrupted ones, which holds on the
    # CPU only (docs/training.md): a GPU, if there is one, stays hidden from them.
    env["CUDA_VISIBLE_DEVICES"] = ""
    return env


def read_trace(trace: Path) -> list[tuple[int, int, Path]]:
    """``(pid, epoch, run_dir)`` for every epoch started, in order."""
    if not trace.exists():
        return []
    out = []
    for line in trace.read_text().splitlines():
        pid, epoch, run_dir = line.split(" ", 2)
        out.append((int(pid), int(epoch), Path(run_dir)))
    return out


def committed_epochs(run_dir: Path) -> int:
    """Epochs the committed ``checkpoints/last.ckpt`` of a run holds (0 without one)."""
    import torch

    path = Path(run_dir) / "checkpoints" / "last.ckpt"
    if not path.exists():
        return 0
    checkpoint = torch.load(path, weights_only=True, mmap=True)
    return int(checkpoint["callbacks"]["tactile_compliance.EpochState"]["epochs_done"])


def wait_until_midway(
    proc: subprocess.Popen,
    trace: Path,
    one_finished: Callable[[], bool],
    *,
    timeout_s: float,
    what: str,
) -> Path:
    """Poll until one run has finished (``one_finished()``) and another is midway, and
    return the midway run's directory: its epoch 1 has started (so epoch 0 is committed
    to ``last.ckpt``) and it has no ``metrics.json`` yet.

    The kill tests interrupt the command at that moment. Fails (with the command's
    stderr) when ``proc`` ends first, or after ``timeout_s`` seconds; ``what`` names the
    command in those messages.
    """
    deadline = time.monotonic() + timeout_s
    while True:
        assert proc.poll() is None, f"{what} ended first: {proc.communicate()[1][-3000:]}"
        assert time.monotonic() < deadline, f"{what} never got midway"
        finished = one_finished()
        started = {run_dir for _, epoch, run_dir in read_trace(trace) if epoch >= 1}
        unfinished = [d for d in started if not (d / "metrics.json").exists()]
        if finished and unfinished:
            return unfinished[0]
        time.sleep(0.02)


def default_sigint() -> None:
    """``preexec_fn`` for a child that a test interrupts with SIGINT: Ctrl-C's default
    disposition, even when the tests run in a background job (where the shell ignores
    SIGINT, children inherit that, and Python then installs no KeyboardInterrupt)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
