"""``OnnxEstimator``: an exported ONNX file run with onnxruntime behind the estimator API;
the names ``export`` and it agree on (metadata key, output and input names) are defined
here. See docs/inference.md, "ONNX export".
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import torch

from tactile_compliance.data.inputs import InputStrategy
from tactile_compliance.inference.base import BaseEstimator
from tactile_compliance.runs.forward import model_arguments
from tactile_compliance.runs.run_inputs import RunInputs

__all__ = ["ONNX_METADATA_KEY", "OUTPUT_NAME", "OnnxEstimator", "onnx_input_names"]

ONNX_METADATA_KEY = "tactile_compliance"
OUTPUT_NAME = "modulus_normalised"


def onnx_input_names(inputs: InputStrategy | str) -> list[str]:
    """Graph input names for a strategy: its inputs' names (``data.inputs.INPUTS``), image
    first; the image input enters the graph prepared, (B, 3, 3, H, W)."""
    return list(InputStrategy.parse(inputs).input_names)


def _ort_session(path: str | Path, threads: int | None = None) -> Any:
    """A CPU onnxruntime session; ``threads`` fixes intra-op threads (None: its default)."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    if threads is not None:
        options.intra_op_num_threads = int(threads)
        options.inter_op_num_threads = 1
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


class OnnxEstimator(BaseEstimator):
    """The ``predict`` API of :class:`ComplianceEstimator` on an exported ONNX file.

    Args:
        path: an ``.onnx`` file written by :func:`~tactile_compliance.inference.export.
            export_onnx`.
        threads: onnxruntime intra-op threads (None = onnxruntime's default).
    """

    kind = "ONNX model"

    def __init__(self, path: str | Path, *, threads: int | None = None) -> None:
        self.source = str(path)
        self.session = _ort_session(path, threads)
        meta = self.session.get_modelmeta().custom_metadata_map
        if ONNX_METADATA_KEY not in meta:
            raise ValueError(f"{path}: not exported by tactile-compliance (no metadata)")
        self.meta: dict[str, Any] = json.loads(meta[ONNX_METADATA_KEY])
        self.run_inputs = RunInputs.from_dict(self.meta.get("run_inputs"), self.source)
        self.input_names: list[str] = list(self.meta["input_names"])

    @property
    def model_name(self) -> str:
        """The exported model's registry name, from the file's metadata."""
        return str(self.meta["model"])

    def _forward(self, chunk: dict[str, torch.Tensor]) -> np.ndarray:
        """Normalised outputs of one prepared chunk through onnxruntime; the graph takes
        the image input resized and normalised, here by ``model_arguments``, the one
        forward path's preparation."""
        images, scalars = model_arguments(chunk, self.run_inputs)
        feed = {name: tensor.numpy() for name, tensor in scalars.items()}
        image = self.run_inputs.inputs.image
        if image is not None:
            feed[image.name] = images.numpy()
        return self.session.run([OUTPUT_NAME], feed)[0]
