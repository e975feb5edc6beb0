"""Dask clients for grids and tuning: a local cluster by default, or an existing scheduler.

See docs/experiments.md, "Dask: local, existing scheduler, SLURM/PBS".
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

__all__ = ["available_cpus", "dask_client", "limit_threads"]


def available_cpus() -> int:
    """CPUs this process may run on (affinity-aware where the OS tells)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def limit_threads(threads: int | None) -> None:
    """Let torch use ``threads`` threads in this process (a worker); None or 0 leaves it.

    Called at the start of every grid cell and tuning trial, because Dask workers are
    separate processes and each starts with torch's default (all cores)."""
    if threads:
        import torch

        torch.set_num_threads(int(threads))


@contextmanager
def dask_client(
    workers: int = 1, scheduler: str | None = None, client: Any = None
) -> Iterator[Any]:
    """Yield a ``distributed.Client``: ``client`` as is, a scheduler's, or a local cluster's.

    A cluster or client this function starts is closed on exit, also after an exception
    or Ctrl-C, so no worker processes are left behind.

    Args:
        workers: local worker processes (ignored with ``scheduler`` or ``client``).
        scheduler: address ``tcp://host:port`` or path of a scheduler JSON file.
        client: an existing client (not closed on exit).
    """
    if client is not None:
        yield client
        return
    import distributed

    if scheduler:
        if Path(scheduler).is_file():
            remote = distributed.Client(scheduler_file=str(scheduler), timeout="30s")
        else:
            remote = distributed.Client(scheduler, timeout="30s")
        try:
            yield remote
        finally:
            remote.close()
        return
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    import dask

    # Non-daemonic workers may start DataLoader worker processes (training.num_workers > 0).
    with dask.config.set({"distributed.worker.daemon": False}):
        cluster = distributed.LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=logging.ERROR,
            memory_limit="auto",  # per worker: the machine's memory x threads / CPUs
        )
    local = distributed.Client(cluster)
    try:
        yield local
    finally:
        local.close()
        cluster.close()
