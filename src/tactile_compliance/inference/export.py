"""Export a checkpoint: its full forward pass to ONNX (checked against PyTorch), or its
weights to a safetensors directory (``inference/pretrained.py``). See docs/inference.md,
"ONNX export" (graph inputs, exporter, the pool rewrite) and "Deployable weights".
"""

from __future__ import annotations

import contextlib
import copy
import json
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from tactile_compliance.data.inputs import INPUTS
from tactile_compliance.inference.estimator import ComplianceEstimator
from tactile_compliance.inference.model_card import DEFAULT_LICENSE, check_license
from tactile_compliance.inference.onnx import (
    ONNX_METADATA_KEY,
    OUTPUT_NAME,
    _ort_session,
    onnx_input_names,
)
from tactile_compliance.inference.pretrained import (
    OUTPUT_KIND,
    OptionalDependencyError,
    check_export_dir,
    refuse_output_calibration,
    require_safetensors,
    run_evaluation,
    write_pretrained,
)
from tactile_compliance.outputs import atomic_file, check_output_file, claim_output_dir

__all__ = [
    "check_onnx_output",
    "export_onnx",
    "export_safetensors",
    "format_export_report",
    "format_safetensors_report",
]

DEFAULT_OPSET = 17


class _ExportWrapper(nn.Module):
    """Positional inputs in ``onnx_input_names`` order -> the model's keyword call."""

    def __init__(self, model: nn.Module, names: list[str]) -> None:
        super().__init__()
        self.model = model
        self.names = names

    def forward(self, *args: torch.Tensor) -> torch.Tensor:
        named = dict(zip(self.names, args, strict=True))
        images = next((named.pop(n) for n in self.names if INPUTS[n].kind == "image"), None)
        return self.model(images, **named)


def _pool_matrix(size_in: int, size_out: int) -> torch.Tensor:
    """(size_out, size_in) averaging matrix of PyTorch's adaptive pooling along one axis."""
    matrix = torch.zeros(size_out, size_in)
    for i in range(size_out):
        start = (i * size_in) // size_out
        end = -((-(i + 1) * size_in) // size_out)  # ceil((i + 1) * size_in / size_out)
        matrix[i, start:end] = 1.0 / (end - start)
    return matrix


class _FixedAdaptiveAvgPool2d(nn.Module):
    """``AdaptiveAvgPool2d`` for one known input size, as ``P_h @ x @ P_w^T`` (exportable)."""

    def __init__(self, size_in: tuple[int, int], size_out: tuple[int, int]) -> None:
        super().__init__()
        self.register_buffer("rows", _pool_matrix(size_in[0], size_out[0]))
        self.register_buffer("cols", _pool_matrix(size_in[1], size_out[1]).t().contiguous())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.matmul(torch.matmul(self.rows, x), self.cols)


def _exportable(model: nn.Module, names: list[str], example: tuple[torch.Tensor, ...]) -> nn.Module:
    """A copy of ``model`` whose adaptive average pools have fixed, exportable sizes."""
    model = copy.deepcopy(model).eval()
    pools = {
        name: module
        for name, module in model.named_modules()
        if isinstance(module, nn.AdaptiveAvgPool2d)
    }
    if not pools:
        return model
    seen: dict[str, tuple[int, int]] = {}
    hooks = [
        module.register_forward_hook(
            lambda mod, inp, out, name=name: seen.__setitem__(name, tuple(inp[0].shape[-2:]))
        )
        for name, module in pools.items()
    ]
    try:
        with torch.no_grad():
            _ExportWrapper(model, names)(*example)
    finally:
        for hook in hooks:
            hook.remove()
    for name, module in pools.items():
        out = module.output_size
        out_hw = (out, out) if isinstance(out, int) else tuple(out)
        if name not in seen or None in out_hw:
            continue
        parent_name, _, attr = name.rpartition(".")
        parent = model.get_submodule(parent_name) if parent_name else model
        setattr(parent, attr, _FixedAdaptiveAvgPool2d(seen[name], out_hw))  # type: ignore[arg-type]
    return model


def _input_shape(name: str, batch: Any, image_size: tuple[int, int] | None) -> list[Any]:
    """The graph's shape of input ``name``: prepared images (B, 3, 3, H, W), scalars (B, n)."""
    if INPUTS[name].kind == "image":
        assert image_size is not None  # a strategy with an image has an image size
        return [batch, 3, 3, *image_size]
    return [batch, INPUTS[name].size]


def _example_inputs(
    names: list[str], batch: int, image_size: tuple[int, int] | None, seed: int = 0
) -> tuple[torch.Tensor, ...]:
    """Normalised-looking random inputs (images ~ N(0, 1), scalars in [0, 1])."""
    gen = torch.Generator().manual_seed(seed)
    return tuple(
        torch.randn(*_input_shape(n, batch, image_size), generator=gen)
        if INPUTS[n].kind == "image"
        else torch.rand(*_input_shape(n, batch, image_size), generator=gen)
        for n in names
    )


def _is_our_onnx(path: Path) -> bool:
    """Whether ``path`` is an ONNX model written by :func:`export_onnx` (safe to replace)."""
    import onnx

    model = onnx.load(str(path), load_external_data=False)
    return any(prop.key == ONNX_METADATA_KEY for prop in model.metadata_props)


def check_onnx_output(out: str | Path) -> Path:
    """Refuse an ``--onnx`` path that is a link, a directory or a file this package did
    not write (``outputs.check_output_file``), before anything is computed."""
    return check_output_file(out, "ONNX model", _is_our_onnx, option="--onnx")


class OnnxMissingError(OptionalDependencyError):
    """``onnx`` or ``onnxruntime`` (the ``export`` extra) is not installed."""


def require_onnx() -> None:
    """Check that ``onnx`` and ``onnxruntime`` import, before anything is written."""
    missing = []
    for name in ("onnx", "onnxruntime"):
        try:
            __import__(name)
        except ImportError:
            missing.append(name)
    if missing:
        raise OnnxMissingError(
            f"{' and '.join(missing)} {'is' if len(missing) == 1 else 'are'} not installed: "
            f"pip install 'tactile-compliance[export]' (or pip install {' '.join(missing)})"
        )


def export_onnx(
    checkpoint: str | Path,
    out: str | Path,
    *,
    opset: int = DEFAULT_OPSET,
    check: bool = True,
    atol: float = 1e-4,
    check_batch_sizes: tuple[int, ...] = (1, 3),
    backbone_weights: str | Path | None = None,
) -> dict[str, Any]:
    """Export a checkpoint to ONNX (dynamic batch) and check it against PyTorch.

    Args:
        checkpoint: ``best.pt`` or a run directory.
        out: the ``.onnx`` file to write (replaced atomically).
        check: run onnxruntime on random inputs at ``check_batch_sizes`` and compare.
        atol: largest acceptable absolute difference of the normalised output.
        backbone_weights: a local copy of a frozen backbone's weights file.

    Returns:
        A report: ``onnx_path``, ``inputs`` (name -> shape), ``output``, ``image_size``,
        ``opset``, ``exporter``, ``max_abs_diff``, ``parity_ok``, versions, file size.

    Raises:
        OnnxMissingError: onnx or onnxruntime is not installed (nothing is written).
        RuntimeError: parity worse than ``atol``.
    """
    require_onnx()
    out = check_onnx_output(out)
    estimator = ComplianceEstimator.from_checkpoint(checkpoint, backbone_weights=backbone_weights)
    refuse_output_calibration(estimator)
    image_size = estimator.run_inputs.image_size
    names = onnx_input_names(estimator.inputs)
    model = estimator.model.cpu().eval()
    example = _example_inputs(names, 2, image_size)
    wrapper = _ExportWrapper(_exportable(model, names, example), names).eval()
    # The folders this export creates (deepest first): removed again if it fails, so a
    # failed export leaves no empty folder behind.
    created = [folder for folder in (out.parent, *out.parent.parents) if not folder.exists()]
    out.parent.mkdir(parents=True, exist_ok=True)
    try:
        # Written by name into the temp file, which atomic_file then renames into place.
        with atomic_file(out, "wb", unique=True) as handle:
            with warnings.catch_warnings():
                # The TorchScript exporter is deprecated (docs/inference.md, "Exporter") and
                # warns about shape-dependent Python code, constant for a fixed frame size.
                warnings.simplefilter("ignore")
                torch.onnx.export(
                    wrapper,
                    example,
                    handle.name,
                    dynamo=False,
                    input_names=names,
                    output_names=[OUTPUT_NAME],
                    dynamic_axes={name: {0: "batch"} for name in [*names, OUTPUT_NAME]},
                    opset_version=opset,
                    do_constant_folding=True,
                )
            _write_metadata(Path(handle.name), estimator, names)
    except BaseException:
        for folder in created:
            with contextlib.suppress(OSError):  # not empty: something else wrote there
                folder.rmdir()
        raise

    import onnxruntime

    report: dict[str, Any] = {
        "onnx_path": str(out),
        "checkpoint": estimator.source,
        "model": estimator.model_name,
        "strategy": estimator.inputs.value,
        "inputs": {name: _input_shape(name, "batch", image_size) for name in names},
        "output": {OUTPUT_NAME: ["batch"]},
        "image_size": None if image_size is None else list(image_size),
        "opset": opset,
        "exporter": "torch.onnx.export(dynamo=False) (TorchScript-based)",
        "torch_version": torch.__version__,
        "onnxruntime_version": onnxruntime.__version__,
        "file_size_bytes": out.stat().st_size,
        "atol": atol,
    }
    if check:
        diff = onnx_parity(out, model, names, image_size, check_batch_sizes)
        report.update(
            max_abs_diff=diff, parity_ok=diff <= atol, batch_sizes_checked=list(check_batch_sizes)
        )
        if diff > atol:
            raise RuntimeError(
                f"ONNX output differs from PyTorch by {diff:.3g} (> {atol:g}); {out} kept "
                f"for inspection"
            )
    return report


def onnx_parity(
    path: str | Path,
    model: nn.Module,
    names: list[str],
    image_size: tuple[int, int] | None,
    batch_sizes: tuple[int, ...] = (1, 3),
) -> float:
    """Largest |ONNX - PyTorch| of the normalised output over random inputs."""
    session = _ort_session(path)
    wrapper = _ExportWrapper(model, names).eval()
    worst = 0.0
    for i, batch in enumerate(batch_sizes):
        inputs = _example_inputs(names, batch, image_size, seed=100 + i)
        with torch.no_grad():
            expected = wrapper(*inputs)
        got = session.run([OUTPUT_NAME], {n: t.numpy() for n, t in zip(names, inputs, strict=True)})
        worst = max(worst, float(np.max(np.abs(got[0] - expected.numpy()))))
    return worst


def _write_metadata(path: Path, estimator: ComplianceEstimator, names: list[str]) -> None:
    import onnx

    proto = onnx.load(str(path))
    description = {
        "model": estimator.model_name,
        "input_names": names,
        "output_name": OUTPUT_NAME,
        "run_inputs": estimator.run_inputs.to_dict(),
        "checkpoint": estimator.source,
        "seed": estimator.meta.get("seed"),
        "package_version": estimator.meta.get("package_version"),
    }
    entry = proto.metadata_props.add()
    entry.key = ONNX_METADATA_KEY
    entry.value = json.dumps(description)
    proto.doc_string = (
        f"tactile-compliance {estimator.model_name} ({estimator.inputs.value}): normalised "
        f"inputs {names} -> {OUTPUT_NAME} = (log10 E - lo) / (hi - lo)"
    )
    onnx.save(proto, str(path))


def _images(size: list[int] | None) -> str:
    """``images 48x64`` or ``no images`` (a frame-free model), for the reports."""
    return "no images" if size is None else f"images {size[0]}x{size[1]}"


def format_export_report(report: dict[str, Any]) -> str:
    """Human-readable text of an :func:`export_onnx` report (what the CLI prints)."""
    inputs = ", ".join(
        f"{name} {tuple(shape)}".replace("'", "") for name, shape in report["inputs"].items()
    )
    lines = [
        f"Wrote {report['onnx_path']} ({report['file_size_bytes'] / 1e6:.1f} MB, opset "
        f"{report['opset']}, {report['exporter']})",
        f"Model     {report['model']} inputs={report['strategy']}, {_images(report['image_size'])}",
        f"Inputs    {inputs} (normalised; see docs/inference.md)",
        f"Output    {OUTPUT_NAME} (batch,) = (log10 E - lo) / (hi - lo)",
    ]
    if "max_abs_diff" in report:
        sizes = ", ".join(map(str, report["batch_sizes_checked"]))
        verdict = "OK" if report["parity_ok"] else "FAILED"
        lines.append(
            f"Parity    max |ONNX - PyTorch| = {report['max_abs_diff']:.2e} at batch sizes "
            f"{sizes} (onnxruntime {report['onnxruntime_version']}; tolerance "
            f"{report['atol']:g}): {verdict}"
        )
    return "\n".join(lines)


def export_safetensors(
    checkpoint: str | Path,
    out: str | Path,
    *,
    backbone_weights: str | Path | None = None,
    license: str = DEFAULT_LICENSE,
) -> dict[str, Any]:
    """Write a checkpoint as ``model.safetensors`` + ``config.json`` + a model card ``README.md``
    (``out``: new, empty or an earlier export; ``license``: an SPDX identifier or ``other``).

    Returns:
        ``out``, ``files`` (name -> bytes), ``config`` (what ``config.json`` holds).
    """
    # Refused (a user's directory or a link to one, a licence that is no identifier,
    # safetensors missing) before the checkpoint is read.
    require_safetensors()
    check_license(license)
    check_export_dir(out)
    # Checked, not created: a missing checkpoint must not leave an empty OUT behind.
    claim_output_dir(out, OUTPUT_KIND, option="--safetensors", create=False)
    estimator = ComplianceEstimator.from_checkpoint(checkpoint, backbone_weights=backbone_weights)
    file = Path(estimator.source)
    return write_pretrained(
        estimator, out, checkpoint=file, evaluation=run_evaluation(file), license=license
    )


def format_safetensors_report(report: dict[str, Any]) -> str:
    """Human-readable text of an :func:`export_safetensors` report (what the CLI prints)."""
    config = report["config"]
    sizes = ", ".join(f"{name} {size / 1e6:.2f} MB" for name, size in report["files"].items())
    run_inputs = config["run_inputs"]
    return "\n".join(
        [
            f"Wrote {report['out']} ({sizes})",
            f"Model     {config['model_name']} inputs={run_inputs['inputs']}, "
            f"{_images(run_inputs['image_size'])} {run_inputs['channel_order']}",
            f"Load      ComplianceEstimator.from_pretrained({report['out']!r})",
        ]
    )
