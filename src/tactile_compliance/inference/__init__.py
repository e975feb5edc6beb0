"""Inference: load a checkpoint, predict Young's modulus (Pa), stream, ensemble, export.
Each module's contents: docs/inference.md, "Files".
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
