"""Where a model runs: the one default device and the one resolver of ``auto``.

torch is imported when a device is resolved, not with this module.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import torch

__all__ = ["DEFAULT_DEVICE", "resolve_device"]

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
