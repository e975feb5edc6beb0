"""Self-describing model checkpoints (``best.pt``), loadable with ``weights_only=True``.

A frozen backbone is recorded (how to rebuild it, its sha256), not stored. See
docs/training.md, "Checkpoints describe themselves", and docs/models.md ("Recorded
downstream") for ``backbone_weights_file``.
"""

from __future__ import annotations

import contextlib
import math
import os
import warnings
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from tactile_compliance import __version__
from tactile_compliance.data.features import weights_fingerprint
from tactile_compliance.data.safe_pickle import load_torch_file
from tactile_compliance.devices import DEFAULT_DEVICE, resolve_device
from tactile_compliance.models import create_model, get_model_class
from tactile_compliance.models.backbones import PRETRAIN_KEY, file_sha256, load_mapped, no_downloads
from tactile_compliance.outputs import atomic_file, check_format_version
from tactile_compliance.runs.run_inputs import RunInputs

CHECKPOINT_FORMAT = "tactile-compliance-model"
#: 3: the input contract is one ``run_inputs`` record (``runs.run_inputs.RunInputs``).
CHECKPOINT_VERSION = 3

#: Seed of a randomly initialised frozen backbone. Independent of the run seed so that
#: every seed and trial shares one backbone and therefore one feature cache; recorded in
#: head-only checkpoints, which rebuild the backbone from it.
FROZEN_BACKBONE_SEED = 0

BACKBONE_PREFIX = "backbone."

# Per backbone tensor, the summary keeps its L2 norm and this many evenly spaced values.
_SUMMARY_VALUES = 8
# torch's CPU random initialisation differs between instruction sets (AVX2 vs the
# default kernel used e.g. on ARM) by a few float32 ulps, i.e. ~5e-7 of a value: the
# sha256 then differs although the backbone is the same function. This tolerance
# (relative to the tensor's RMS) accepts that and nothing coarser.
_SUMMARY_RTOL = 1e-5


@dataclass
class LoadedModel:
    """A model rebuilt from a checkpoint plus what it needs for its input pipeline."""

    model: torch.nn.Module
    run_inputs: RunInputs
    meta: dict[str, Any]


def create_seeded_model(name: str, seed: int, **kwargs: Any) -> torch.nn.Module:
    """``create_model(name, **kwargs)`` under ``torch.manual_seed(seed)``.

    This is what a frozen random backbone *is*: training takes its backbone from such a
    model and :func:`load_checkpoint` rebuilds it the same way. The caller's random
    state is left as it was.
    """
    with torch.random.fork_rng():
        torch.manual_seed(seed)
        return create_model(name, **kwargs)


def _backbone_summary(backbone: torch.nn.Module) -> dict[str, list[float]]:
    """Per tensor: [L2 norm, then ``_SUMMARY_VALUES`` evenly spaced values] (float64)."""
    summary = {}
    for name, tensor in backbone.state_dict().items():
        flat = tensor.detach().reshape(-1).to(torch.float64).cpu()
        last, count = flat.numel() - 1, min(_SUMMARY_VALUES, flat.numel())
        # Integer positions: a float32 linspace rounds past the end of 100M-element tensors.
        index = torch.tensor([i * last // max(1, count - 1) for i in range(count)])
        summary[name] = [float(flat.norm()), *flat[index].tolist()]
    return summary


def _same_up_to_rounding(
    backbone: torch.nn.Module, recorded: dict[str, list[float]] | None
) -> bool:
    """Whether ``backbone`` matches a recorded summary within float32 rounding."""
    actual = _backbone_summary(backbone)
    if not recorded or set(recorded) != set(actual):
        return False
    sizes = {name: tensor.numel() for name, tensor in backbone.state_dict().items()}
    for name, values in actual.items():
        expected = recorded[name]
        if len(expected) != len(values):
            return False
        norm = values[0]
        rms = norm / math.sqrt(max(1, sizes[name]))
        if abs(norm - expected[0]) > _SUMMARY_RTOL * norm:
            return False
        pairs = zip(values[1:], expected[1:], strict=True)
        if any(abs(a - b) > _SUMMARY_RTOL * rms for a, b in pairs):
            return False
    return True


def frozen_backbone_record(model: torch.nn.Module, *, seed: int | None) -> dict[str, Any]:
    """How to rebuild ``model``'s frozen backbone, for a head-only checkpoint.

    ``{"weights", "seed", "sha256", "summary"}``: the weights source (``none``, ``imagenet``
    or a file's absolute path), the ``seed`` the random backbone was created under
    (:func:`create_seeded_model`; None unless random), the sha256 of the backbone's tensors
    and a small per-tensor summary that tells float rounding from other weights.
    """
    weights = str(getattr(model, "backbone_weights", "none")).strip()
    if weights.lower() in ("none", "imagenet"):
        weights = weights.lower()
    else:
        # A path relative to the training process's directory means nothing to a reader.
        weights = str(Path(weights).expanduser().resolve())
    if weights == "none" and seed is None:
        raise ValueError("a randomly initialised frozen backbone needs the seed it was made with")
    return {
        "weights": weights,
        "seed": int(seed) if weights == "none" and seed is not None else None,
        "sha256": weights_fingerprint(model.backbone),
        "summary": _backbone_summary(model.backbone),
    }


def backbone_weights_file_record(model: torch.nn.Module) -> dict[str, Any] | None:
    """``{"path", "sha256", "provenance"}`` of the local weights file ``model``'s backbone
    was initialised from: its absolute path, the sha256 of its bytes and the provenance a
    ``pretrain`` file carries under ``PRETRAIN_KEY`` (else None); None for random or
    ImageNet weights. Hashes the file: compute it once per run."""
    weights = str(getattr(model, "backbone_weights", "none")).strip()
    if weights.lower() in ("none", "imagenet"):
        return None
    file = Path(weights).expanduser().resolve()
    loaded = load_mapped(file)  # the tensors are not read, only the provenance record
    record = loaded.get(PRETRAIN_KEY) if isinstance(loaded, Mapping) else None
    provenance = dict(record) if isinstance(record, Mapping) else None
    return {"path": str(file), "sha256": file_sha256(file), "provenance": provenance}


def save_checkpoint(
    path: str | Path,
    model: torch.nn.Module,
    *,
    run_inputs: RunInputs,
    config: dict[str, Any],
    seed: int,
    metrics: dict[str, Any] | None = None,
    frozen_backbone: dict[str, Any] | None = None,
    backbone_weights_file: dict[str, Any] | None = None,
    store: dict[str, Any] | None = None,
) -> Path:
    """Write ``model`` and its description to ``path`` (atomically).

    ``frozen_backbone``: the :func:`frozen_backbone_record` of a frozen backbone, whose
    tensors are then left out. Compute it once, before training: it describes the backbone
    the head was trained on (and the feature cache computed with), and hashing VGG16 takes
    ~0.6 s. ``backbone_weights_file``: :func:`backbone_weights_file_record` (None: random
    or ImageNet weights). ``store``: the training store's path and ``header.json``, so a
    model card can say what the model was trained on even where that store is gone.
    """
    path = Path(path)
    state = {
        k: v.detach().cpu()
        for k, v in model.state_dict().items()
        # Filter before .cpu(): a frozen VGG16 on a GPU is 0.5 GB not worth copying.
        if frozen_backbone is None or not k.startswith(BACKBONE_PREFIX)
    }
    payload = {
        "format": CHECKPOINT_FORMAT,
        "format_version": CHECKPOINT_VERSION,
        "package_version": __version__,
        "model_name": model.model_name,
        "run_inputs": run_inputs.to_dict(),
        "hparams": dict(model.hparams),
        "backbone_weights": str(getattr(model, "backbone_weights", "none")),
        "store": store,
        "config": config,
        "seed": int(seed),
        "metrics": metrics or {},
        "backbone": frozen_backbone,
        "backbone_weights_file": backbone_weights_file,
        "state_dict": state,
    }
    # Temp file, fsync, rename: a full disk or a kill leaves the old file and no temp file.
    with atomic_file(path, "wb") as handle, torch_write_errors(path):
        torch.save(payload, handle)
    return path


@contextlib.contextmanager
def torch_write_errors(path: str | Path) -> Iterator[None]:
    """Let a failed ``torch.save`` raise the ``OSError`` it is.

    torch's zip writer reports a failed write (a full disk) as ``RuntimeError('[enforce
    fail at inline_container.cc] unexpected pos ...')`` with the ``OSError`` only as its
    context; the CLI turns an ``OSError`` into one line (a full disk: exit code 1).
    """
    try:
        yield
    except RuntimeError as err:
        cause = err.__context__
        if not isinstance(cause, OSError):
            raise
        raise OSError(cause.errno, f"cannot write {path}: {cause.strerror}") from err


def _rebuild_with_frozen_backbone(
    path: Path, payload: dict[str, Any], inputs: str, weights: str | os.PathLike[str] | None
) -> torch.nn.Module:
    """The model of a head-only checkpoint with its backbone rebuilt and verified."""
    record = payload["backbone"]
    name = payload["model_name"]
    kwargs: dict[str, Any] = {"inputs": inputs, **payload["hparams"]}
    takes_weights = getattr(get_model_class(name), "pretrained_backbone", False)
    source = os.fspath(weights) if weights is not None else str(record["weights"])
    if source.lower() == "none":
        if record.get("seed") is None:
            raise ValueError(f"{path}: the frozen random backbone has no recorded seed")
        if takes_weights:
            kwargs["backbone_weights"] = "none"
        model = create_seeded_model(name, int(record["seed"]), **kwargs)
        described = f"random initialisation with seed {record['seed']}"
    else:
        if not takes_weights:
            raise ValueError(f"{path}: model {name!r} takes no backbone weights ({source!r})")
        if source.lower() != "imagenet" and not Path(source).expanduser().is_file():
            raise FileNotFoundError(
                f"{path}: the frozen backbone's weights file {source} does not exist here "
                f"(head-only checkpoint). Pass a copy of it with `--weights PATH` "
                f"(in Python: backbone_weights=PATH)."
            )
        try:
            with no_downloads():
                model = create_model(name, **kwargs, backbone_weights=source)
        except RuntimeError as err:  # a corrupted file or one of another architecture
            raise ValueError(f"{path}: cannot rebuild the frozen backbone: {err}") from err
        described = f"weights {source!r}"
    actual = weights_fingerprint(model.backbone)
    if actual != record["sha256"]:
        if not _same_up_to_rounding(model.backbone, record.get("summary")):
            hint = (
                "torch's random initialisation changed (another torch version?)"
                if source.lower() == "none"
                else "pass the weights file the run was trained with (`--weights PATH`)"
            )
            raise ValueError(
                f"{path}: the rebuilt frozen backbone ({described}) is not the one the head "
                f"was trained with: its sha256 is {actual[:16]}..., the checkpoint records "
                f"{str(record['sha256'])[:16]}...; {hint}"
            )
        warnings.warn(
            f"{path}: the rebuilt frozen backbone ({described}) matches the recorded one "
            f"only up to float32 rounding (torch's CPU random initialisation differs "
            f"between instruction sets, e.g. AVX2 vs ARM); predictions can differ in the "
            f"sixth significant digit",
            stacklevel=3,
        )
    missing, unexpected = model.load_state_dict(payload["state_dict"], strict=False)
    missing_head = [k for k in missing if not k.startswith(BACKBONE_PREFIX)]
    if missing_head or unexpected:
        raise ValueError(
            f"{path}: the stored head does not fit {name!r}: missing {missing_head}, "
            f"unexpected {unexpected}"
        )
    return model


def load_checkpoint(
    path: str | Path,
    device: str | torch.device = DEFAULT_DEVICE,
    *,
    backbone_weights: str | os.PathLike[str] | None = None,
) -> LoadedModel:
    """Rebuild a model from a checkpoint written by :func:`save_checkpoint` (eval mode).

    The model goes to ``device``: ``auto``, like every command, is a CUDA GPU when torch
    sees one, so inputs must be moved to ``next(model.parameters()).device``; ``"cpu"``
    keeps it beside CPU tensors on any machine.

    Nothing is downloaded. A head-only checkpoint (frozen backbone) rebuilds its backbone
    from the recorded seed, the torch.hub cache (``imagenet``) or the recorded file;
    ``backbone_weights`` (a file) replaces that source, e.g. a copy of the ImageNet file
    on an offline machine. Either way the backbone must have the recorded sha256.

    Raises:
        FileNotFoundError: no checkpoint, or the backbone's weights file is not available.
        ValueError: not a checkpoint, another format version, or a rebuilt backbone whose
            fingerprint differs from the recorded one.
    """
    path = Path(path)
    device = resolve_device(device)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: checkpoint not found")
    payload = load_torch_file(path, "tactile-compliance checkpoint", map_location=device)
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(f"{path}: not a tactile-compliance model checkpoint")
    check_format_version(payload.get("format_version"), CHECKPOINT_VERSION, f"{path}: checkpoint")
    return rebuild_model(path, payload, device, backbone_weights=backbone_weights)


def check_state_dict(source: str | Path, state_dict: Any) -> None:
    """Refuse weights that cannot be a trained model's: a tensor that is not floating point
    (int8, bool: ``load_state_dict`` would cast it silently), NaN or inf values, or a
    weight matrix or kernel (>= 2 dimensions) that is all zero (a dead layer: the model
    predicts a constant). BatchNorm's ``num_batches_tracked`` counters are integers.
    The ValueError names the file and the first bad tensor.
    """
    if not isinstance(state_dict, dict) or not state_dict:
        raise ValueError(f"{source}: holds no weights (an empty or missing state dict)")
    for name, tensor in state_dict.items():
        if not isinstance(tensor, torch.Tensor):
            raise ValueError(f"{source}: weight {name!r} is not a tensor")
        if name.endswith("num_batches_tracked"):
            continue
        if not tensor.is_floating_point():
            raise ValueError(
                f"{source}: weight {name!r} is {tensor.dtype}, not floating point; the file "
                f"was altered or is not a trained model's"
            )
        if not bool(torch.isfinite(tensor).all()):
            raise ValueError(f"{source}: weight {name!r} holds NaN or infinite values")
        if tensor.dim() >= 2 and tensor.numel() and not bool(tensor.any()):
            raise ValueError(
                f"{source}: weight {name!r} {tuple(tensor.shape)} is all zero (a dead layer); "
                f"the file was altered or is not a trained model's"
            )


#: The most parameters a loaded model may have: VGG-LSTM's VGG16 backbone has 138 M
#: (0.55 GB as float32); a recorded layer size that makes more is refused before a byte
#: of it is allocated (``img_feature_size: 100000000`` would allocate 410 GB).
MAX_MODEL_PARAMETERS = 500_000_000


def check_model_size(source: str | Path, payload: dict[str, Any], inputs: str) -> None:
    """Refuse (ValueError, one line) a description whose model would not fit its stored
    weights or would be absurdly large, before the model is allocated: the model is built
    on torch's ``meta`` device (shapes only, no memory) and its tensors' shapes are
    compared with the stored ones (a head-only checkpoint: the head's), its size with
    :data:`MAX_MODEL_PARAMETERS`. A model that cannot be built that way is left to the
    real build, which raises what it raises."""
    name, hparams = payload.get("model_name"), payload.get("hparams")
    if not isinstance(name, str) or not isinstance(hparams, dict):
        return
    kwargs = {k: v for k, v in hparams.items() if k != "backbone_weights"}
    try:
        with torch.device("meta"), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            shapes = {
                key: tuple(tensor.shape)
                for key, tensor in create_model(name, inputs=inputs, **kwargs).state_dict().items()
            }
    except Exception:  # wrong hyperparameters, or a model that needs real tensors to build
        return
    stored = payload.get("state_dict") or {}
    head_only = payload.get("backbone") is not None
    for key, shape in shapes.items():
        if head_only and key.startswith(BACKBONE_PREFIX):
            continue
        tensor = stored.get(key)
        if isinstance(tensor, torch.Tensor) and tuple(tensor.shape) != shape:
            raise ValueError(
                f"{source}: the stored weights do not fit {name!r} with the recorded "
                f"hyperparameters: they make {key!r} {list(shape)}, the stored weight is "
                f"{list(tensor.shape)} (refused before building the model)"
            )
    total = sum(math.prod(shape) for shape in shapes.values())
    if total > MAX_MODEL_PARAMETERS:
        raise ValueError(
            f"{source}: the recorded hyperparameters of {name!r} ({str(hparams)[:200]}) make "
            f"a model of {total:.3g} "
            f"parameters, beyond the {MAX_MODEL_PARAMETERS:.0e} any model of this package "
            f"has (refused before allocating it)"
        )


def rebuild_model(
    source: str | Path,
    payload: dict[str, Any],
    device: str | torch.device,
    *,
    backbone_weights: str | os.PathLike[str] | None = None,
) -> LoadedModel:
    """The model a checkpoint's contents describe, with its weights loaded (eval mode).

    The one way a model is rebuilt from a description: :func:`load_checkpoint` calls it on
    a ``best.pt``'s payload, and the safetensors directories of ``export --safetensors``
    (``inference.pretrained``) on their ``config.json`` plus ``model.safetensors``.

    Args:
        source: where the payload came from, for error messages.
        payload: ``model_name``, ``run_inputs`` (:meth:`RunInputs.to_dict`), ``hparams``
            and ``state_dict``; ``backbone`` (a frozen backbone's record)
            when the state dict is the head only; everything else is kept as ``meta``.
        device: where the model goes (``auto``: a CUDA GPU when torch sees one).
        backbone_weights: see :func:`load_checkpoint`.
    """
    path = Path(source)
    # Every loaded number is checked before it is used: a tampered or damaged file fails
    # here with one line instead of predicting NaN, a constant or 9e256 Pa.
    run_inputs = RunInputs.from_dict(payload.get("run_inputs"), str(path))
    inputs = run_inputs.inputs.value
    check_state_dict(path, payload["state_dict"])
    check_model_size(path, payload, inputs)
    if payload.get("backbone") is not None:
        model = _rebuild_with_frozen_backbone(path, payload, inputs, backbone_weights)
    else:
        # The whole state dict is stored: backbone weights come from it, not the network.
        model = create_model(payload["model_name"], inputs=inputs, **payload["hparams"])
        try:
            model.load_state_dict(payload["state_dict"])
        except RuntimeError as err:  # weights of another model or architecture
            raise ValueError(
                f"{path}: the stored weights do not fit {payload['model_name']!r} with the "
                f"recorded hyperparameters: {str(err).splitlines()[0]}"
            ) from err
    model.backbone_weights = payload.get("backbone_weights", "none")
    model.to(resolve_device(device)).eval()
    meta = {k: v for k, v in payload.items() if k != "state_dict"}
    return LoadedModel(model=model, run_inputs=run_inputs, meta=meta)
