"""Where a model runs: the one default device and the one resolver of ``auto``.

torch is imported when a device is resolved, not with this module.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import torch

__all__ = ["DEFAULT_DEVICE", "free_cores", "resolve_device", "torch_threads"]

#: A CUDA GPU when torch sees one, else the CPU.
DEFAULT_DEVICE = "auto"


def resolve_device(
    device: str | torch.device = DEFAULT_DEVICE, *, name: str = "device"
) -> str | torch.device:
    """``auto``: ``cuda`` when torch sees a GPU, else ``cpu``; any other device is returned
    as given (so a resolved device resolves to itself). A CUDA device without a GPU is a
    ValueError naming ``name`` (the option or config key) rather than torch's later, less
    clear failure."""
    import torch

    if isinstance(device, str) and device == DEFAULT_DEVICE:
        return "cuda" if torch.cuda.is_available() else "cpu"
    if str(device).startswith("cuda") and not torch.cuda.is_available():
        raise ValueError(
            f"{name} {device}, but torch {torch.__version__} sees no CUDA GPU; use auto or cpu"
        )
    return device


def free_cores(limit: int = 4) -> int:
    """CPU cores this process may use that other processes are not busy on: the cores it
    may run on less the 1-minute load average (rounded), at least 1 and at most ``limit``.

    Small CPU fits (``calibrate-depth``'s regressor) run fastest on a few threads; with
    torch's default, one thread per core, a loaded machine makes the threads fight for
    the cores (docs/sensors.md, "Timing").
    """
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not on Linux
        cores = os.cpu_count() or 1
    try:
        busy = round(os.getloadavg()[0])
    except OSError:  # pragma: no cover - no load average
        busy = 0
    return max(1, min(limit, cores - busy))


@contextmanager
def torch_threads(threads: int) -> Iterator[None]:
    """torch's intra-op thread count set to ``threads`` inside the block, restored after."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(max(1, int(threads)))
    try:
        yield
    finally:
        torch.set_num_threads(before)
