"""Deployable weights: a directory of ``model.safetensors`` (the whole state dict, a frozen
backbone included), ``config.json`` and the model card ``README.md``, read and written
locally. See docs/inference.md, "Deployable weights (safetensors)".
"""

from __future__ import annotations

import errno
import json
import os
import secrets
import shutil
from pathlib import Path
from typing import TYPE_CHECKING, Any

import torch

from tactile_compliance import __version__
from tactile_compliance.devices import DEFAULT_DEVICE
from tactile_compliance.inference.model_card import DEFAULT_LICENSE, check_license, model_card
from tactile_compliance.models.backbones import file_sha256
from tactile_compliance.outputs import (
    MARKER_NAME,
    OutputExistsError,
    atomic_file,
    check_format_version,
    claim_output_dir,
    exchange_directories,
)
from tactile_compliance.runs.checkpoint import LoadedModel, rebuild_model
from tactile_compliance.runs.layout import RESULT_FILE

if TYPE_CHECKING:
    from tactile_compliance.inference.base import BaseEstimator

__all__ = [
    "CARD_FILE",
    "CONFIG_FILE",
    "OUTPUT_KIND",
    "PRETRAINED_FORMAT",
    "WEIGHTS_FILE",
    "SafetensorsMissingError",
    "check_export_dir",
    "load_pretrained",
    "pretrained_config",
    "require_safetensors",
    "write_pretrained",
]

PRETRAINED_FORMAT = "tactile-compliance-pretrained"
#: 2: the input contract is one ``run_inputs`` record (``runs.run_inputs.RunInputs``).
PRETRAINED_VERSION = 2
WEIGHTS_FILE = "model.safetensors"
CONFIG_FILE = "config.json"
CARD_FILE = "README.md"
#: The ``outputs.claim_output_dir`` kind of an exported directory.
OUTPUT_KIND = "pretrained"
_FRAME_KIND = (
    "difference images (frame - GaussianBlur11x11(no-contact frame)) / 255 + 0.5, "
    "uint8 (u = floor(x * 255)) or float in [0, 1]"
)


class OptionalDependencyError(ImportError):
    """An optional package (an extra of ``pyproject.toml``) that a feature needs is not
    installed; the message says what to ``pip install``."""


class SafetensorsMissingError(OptionalDependencyError):
    """The optional ``safetensors`` package is not installed."""


def require_safetensors() -> Any:
    """The ``safetensors.torch`` module, or a clear error saying how to install it."""
    try:
        import safetensors.torch
    except ImportError as err:
        raise SafetensorsMissingError(
            "safetensors is not installed: pip install 'tactile-compliance[export]' "
            "(or pip install safetensors)"
        ) from err
    return safetensors.torch


# ---------------------------------------------------------------------- config.json
def check_export_dir(out: str | Path) -> Path:
    """Refuse an export directory that is a symbolic link (before anything is written):
    the export replaces the directory by renaming, which would swap out the link and move
    the files of its target."""
    out = Path(out)
    if out.is_symlink():
        raise OutputExistsError(
            f"--safetensors {out} is a symbolic link (to {os.readlink(out)}); nothing was "
            f"written: give the directory itself"
        )
    return out


def run_evaluation(checkpoint: Path) -> dict[str, Any] | None:
    """The run's ``metrics.json`` next to ``checkpoint`` (test/val metrics), if any."""
    try:
        result = json.loads((checkpoint.parent / RESULT_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return result if isinstance(result, dict) and "test" in result else None


def _without_local_paths(value: Any) -> Any:
    """``value`` with every absolute path (``/home/me/stores/ym``) cut to its last part
    (``ym``); relative paths and other strings stay."""
    if isinstance(value, dict):
        return {key: _without_local_paths(item) for key, item in value.items()}
    if isinstance(value, list):
        return [_without_local_paths(item) for item in value]
    if isinstance(value, str) and (
        value.startswith(("/", "~"))  # or an absolute Windows path, C:\\... or C:/...
        or (len(value) > 2 and value[0].isalpha() and value[1] == ":" and value[2] in "\\/")
    ):
        return Path(value).name or value
    return value


def pretrained_config(
    estimator: BaseEstimator,
    *,
    checkpoint: str | Path,
    evaluation: dict[str, Any] | None = None,
    license: str = DEFAULT_LICENSE,
) -> dict[str, Any]:
    """The ``config.json`` of an exported model (plain JSON values only), without the
    exporting machine's absolute paths.

    Args:
        checkpoint: the checkpoint file ``estimator`` was loaded from (hashed).
        evaluation: the run's ``metrics.json``, if any.
        license: an SPDX identifier such as ``mit``, or ``other``.
    """
    meta = estimator.meta
    # A model loaded from an export has its whole state dict (no record) but keeps the
    # record's provenance in the config it was loaded from.
    backbone = meta.get("backbone") or (meta.get("pretrained") or {}).get("frozen_backbone")
    config = {
        "format": PRETRAINED_FORMAT,
        "format_version": PRETRAINED_VERSION,
        "library_name": "tactile-compliance",
        "license": license,
        "package_version": __version__,
        "model_name": estimator.model_name,
        "hparams": dict(meta.get("hparams") or {}),
        "run_inputs": estimator.run_inputs.to_dict(),
        "required_inputs": list(estimator.required_inputs),
        "frames_per_sample": 3,
        "frame_kind": _FRAME_KIND,
        "backbone_weights": str(meta.get("backbone_weights", "none")),
        # Provenance only: the weights file holds the backbone's tensors.
        "frozen_backbone": (
            None
            if backbone is None
            else {k: backbone.get(k) for k in ("weights", "seed", "sha256")}
        ),
        "checkpoint": {
            "file": Path(checkpoint).name,
            "sha256": file_sha256(checkpoint),
            "package_version": meta.get("package_version"),
            "seed": meta.get("seed"),
            "metrics": meta.get("metrics") or {},
        },
        "training_store": meta.get("store"),
        "training_config": meta.get("config") or {},
        "evaluation": evaluation,
    }
    # Through JSON once: the dict returned is exactly what config.json will hold.
    return _without_local_paths(json.loads(json.dumps(config)))


def _payload(config: dict[str, Any], state_dict: dict[str, torch.Tensor]) -> dict[str, Any]:
    """``config.json`` + tensors -> the description ``rebuild_model`` takes."""
    checkpoint = config.get("checkpoint") or {}
    return {
        "model_name": config["model_name"],
        "run_inputs": config["run_inputs"],
        "hparams": config.get("hparams") or {},
        "backbone_weights": config.get("backbone_weights", "none"),
        "backbone": None,  # the state dict is whole
        "seed": checkpoint.get("seed"),
        "package_version": checkpoint.get("package_version"),
        "metrics": checkpoint.get("metrics") or {},
        "config": config.get("training_config") or {},
        "store": config.get("training_store"),
        "pretrained": {k: v for k, v in config.items() if k != "training_config"},
        "state_dict": state_dict,
    }


# ---------------------------------------------------------------------- write / read
def refuse_output_calibration(estimator: BaseEstimator) -> None:
    """Refuse (ValueError) to export a model that ``adapt`` calibrated: the exported formats
    do not carry the calibration, so the export would predict the model's own scale."""
    if getattr(estimator, "calibration", None) is not None:
        raise ValueError(
            f"{estimator.source}: an adapted checkpoint (adapt's output calibration) cannot be "
            "exported yet: the export would drop the calibration; predict and live take the "
            "adapted best.pt"
        )


def write_pretrained(
    estimator: BaseEstimator,
    out: str | Path,
    *,
    checkpoint: str | Path,
    evaluation: dict[str, Any] | None = None,
    license: str = DEFAULT_LICENSE,
) -> dict[str, Any]:
    """Write ``estimator``'s model as a safetensors directory (claimed, never a user's;
    arguments as :func:`pretrained_config`'s).

    Returns:
        A report: ``out``, ``files`` (name -> bytes), ``config`` (the written config).

    Raises:
        OutputExistsError: ``out`` holds something that is not an export.
        SafetensorsMissingError: safetensors is not installed.
    """
    st = require_safetensors()
    check_license(license)
    check_export_dir(out)
    model = getattr(estimator, "model", None)
    if model is None:
        raise ValueError(f"{estimator.source}: only PyTorch estimators can be exported")
    refuse_output_calibration(estimator)
    config = pretrained_config(
        estimator, checkpoint=checkpoint, evaluation=evaluation, license=license
    )
    tensors: dict[str, torch.Tensor] = {}
    storages: set[int] = set()
    for name, value in model.state_dict().items():
        value = value.detach().cpu().contiguous()
        storage = value.untyped_storage().data_ptr()
        # safetensors refuses tensors that share memory (tied weights): copy those only,
        # so a 0.5 GB backbone is not held twice.
        tensors[name] = value.clone() if storage in storages else value
        storages.add(storage)
    created = not Path(out).exists()
    out = claim_output_dir(out, OUTPUT_KIND, option="--safetensors")
    # The three files are written into a hidden sibling directory, then the two
    # directories swap names at once: a reader or a kill sees the old export or the new
    # one, never run B's weights with run A's config.
    staging = out.parent / f".{out.name}.partial-{os.getpid()}-{secrets.token_hex(4)}"
    try:
        claim_output_dir(staging, OUTPUT_KIND, option="--safetensors")
        with atomic_file(staging / WEIGHTS_FILE, "wb") as handle:
            # Written straight to the temp file by name (no copy of the weights in
            # memory); atomic_file then fsyncs it and renames it into place.
            _save_tensors(st, tensors, handle.name)
        config["weights_sha256"] = file_sha256(staging / WEIGHTS_FILE)
        with atomic_file(staging / CONFIG_FILE) as handle:
            handle.write(json.dumps(config, indent=2) + "\n")
        with atomic_file(staging / CARD_FILE) as handle:
            handle.write(
                model_card(
                    config,
                    parameters=sum(t.numel() for t in tensors.values()),
                    files=(WEIGHTS_FILE, CONFIG_FILE),
                )
            )
        exchange_directories(out, staging)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        if created:  # leave no empty export behind (a full disk, Ctrl-C)
            shutil.rmtree(out, ignore_errors=True)
        raise
    # ``staging`` now holds the previous export: keep the files a user added to it.
    ours = {WEIGHTS_FILE, CONFIG_FILE, CARD_FILE, MARKER_NAME}
    for child in staging.iterdir():
        if child.name not in ours and not (out / child.name).exists():
            os.rename(child, out / child.name)
    shutil.rmtree(staging)
    files = {name: (out / name).stat().st_size for name in (WEIGHTS_FILE, CONFIG_FILE, CARD_FILE)}
    return {"out": str(out), "files": files, "config": config}


def _save_tensors(st: Any, tensors: dict[str, torch.Tensor], path: str) -> None:
    """``safetensors.torch.save_file``, its write errors (a full disk) as ``OSError``."""
    try:
        st.save_file(tensors, path, metadata={"format": "pt"})
    except OSError:
        raise
    except Exception as err:  # safetensors' own error type wraps the I/O error's text
        text = str(err)
        full = "StorageFull" in text or "os error 28" in text or "code: 28" in text
        raise OSError(
            errno.ENOSPC if full else errno.EIO,
            f"cannot write {WEIGHTS_FILE}: {'no space left on device' if full else text}",
            path,
        ) from err


def load_pretrained(path: str | Path, device: str | torch.device = DEFAULT_DEVICE) -> LoadedModel:
    """Rebuild the model of an exported directory with ``runs.checkpoint.rebuild_model``,
    the rebuild ``best.pt`` goes through, so both give the same predictions. Reads local
    files only: nothing is downloaded and no pickled code runs.

    Raises:
        FileNotFoundError: no such directory, or one without ``config.json`` or
            ``model.safetensors``.
        SafetensorsMissingError: safetensors is not installed.
        ValueError: not an export of this package, a newer format, or weights that do
            not fit the model ``config.json`` describes.
    """
    directory = Path(path)
    if not directory.is_dir():
        raise FileNotFoundError(f"{directory}: no such directory (an `export --safetensors` one)")
    missing = [name for name in (CONFIG_FILE, WEIGHTS_FILE) if not (directory / name).is_file()]
    if missing:
        raise FileNotFoundError(
            f"{directory}: missing {' and '.join(missing)}; a model directory written by "
            f"`tactile-compliance export CHECKPOINT --safetensors DIR` holds {WEIGHTS_FILE}, "
            f"{CONFIG_FILE} and {CARD_FILE}"
        )
    config = _read_config(directory / CONFIG_FILE)
    weights = directory / WEIGHTS_FILE
    actual = file_sha256(weights)
    if actual != config["weights_sha256"]:
        raise ValueError(
            f"{weights}: its sha256 {actual[:16]}... is not the {config['weights_sha256'][:16]}"
            f"... that {CONFIG_FILE} records: the weights were replaced or damaged, or belong "
            f"to another export; export the checkpoint again"
        )
    st = require_safetensors()
    try:
        tensors = st.load_file(str(directory / WEIGHTS_FILE), device="cpu")
    except Exception as err:  # safetensors raises its own error type for corrupt files
        raise ValueError(
            f"{directory / WEIGHTS_FILE}: not a readable safetensors file ({err})"
        ) from err
    try:
        return rebuild_model(directory, _payload(config, tensors), device)
    except (TypeError, KeyError) as err:  # hyperparameters the model does not take
        raise ValueError(
            f"{directory / CONFIG_FILE}: cannot rebuild {config['model_name']!r} from it: {err}"
        ) from err


def _read_config(path: Path) -> dict[str, Any]:
    """``config.json``, its fields' types checked (one line for any problem)."""
    try:
        config = json.loads(path.read_text(encoding="utf-8"))
    except (ValueError, RecursionError) as err:  # RecursionError: absurdly deep nesting
        reason = "nested too deeply" if isinstance(err, RecursionError) else str(err)
        raise ValueError(f"{path}: not valid JSON ({reason})") from None
    if not isinstance(config, dict) or config.get("format") != PRETRAINED_FORMAT:
        raise ValueError(
            f"{path}: not a tactile-compliance model config (format {PRETRAINED_FORMAT!r} expected)"
        )
    check_format_version(config.get("format_version"), PRETRAINED_VERSION, f"{path}: model config")
    required = {
        "model_name": str,
        "run_inputs": dict,
        "weights_sha256": str,
    }
    missing_keys = [k for k in required if k not in config]
    if missing_keys:
        raise ValueError(f"{path}: missing {', '.join(missing_keys)}")
    for key, kind in {**required, "hparams": dict}.items():
        if key in config and not isinstance(config[key], kind):
            raise ValueError(f"{path}: {key} must be a JSON {kind.__name__}, got {config[key]!r}")
    return config
