"""Inference: load a checkpoint, predict Young's modulus (Pa), stream, ensemble, export.

:class:`ComplianceEstimator` (a PyTorch checkpoint or an exported safetensors directory)
and :class:`OnnxEstimator` (an ONNX file) share :class:`BaseEstimator`'s ``predict(frames,
force, width, estimates)``; :class:`StreamingEstimator` takes a live sensor's frames one at
a time and :class:`EnsembleEstimator` combines checkpoints (mean and interval in decades);
:func:`export_onnx` and :func:`export_safetensors` export; :func:`predict_path` and
:func:`live_estimates` are the ``predict`` and ``live`` commands. Each module's contents:
``docs/inference.md``, "Files".
"""

from tactile_compliance.data.frame_selection import select_frame_indices
from tactile_compliance.inference.base import BaseEstimator, Prediction
from tactile_compliance.inference.ensemble import EnsembleEstimator, EnsemblePrediction
from tactile_compliance.inference.estimator import ComplianceEstimator
from tactile_compliance.inference.export import (
    export_onnx,
    export_safetensors,
    format_export_report,
)
from tactile_compliance.inference.live import live_estimates
from tactile_compliance.inference.onnx import OnnxEstimator
from tactile_compliance.inference.predict import format_predictions, predict_path
from tactile_compliance.inference.sources import GraspBatch, read_source
from tactile_compliance.inference.streaming import (
    StreamEstimate,
    StreamingEstimator,
    predict_trajectory,
)

__all__ = [
    "BaseEstimator",
    "ComplianceEstimator",
    "EnsembleEstimator",
    "EnsemblePrediction",
    "GraspBatch",
    "OnnxEstimator",
    "Prediction",
    "StreamEstimate",
    "StreamingEstimator",
    "export_onnx",
    "export_safetensors",
    "format_export_report",
    "format_predictions",
    "live_estimates",
    "predict_path",
    "predict_trajectory",
    "read_source",
    "select_frame_indices",
]
