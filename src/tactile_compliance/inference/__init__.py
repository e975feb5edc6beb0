"""Inference: load a checkpoint, predict Young's modulus (Pa), stream, ensemble, export.

* :class:`BaseEstimator` - the ``predict(frames, force, width, estimates)`` API for one
  grasp or a batch, with the input checks and :class:`Prediction`, shared by the PyTorch
  and ONNX estimators (``base.py``).
* :class:`ComplianceEstimator` - ``from_checkpoint(path)``: a PyTorch checkpoint
  (``estimator.py``).
* :class:`StreamingEstimator` - frames with force/width one at a time from a live sensor
  (``streaming.py``).
* :class:`EnsembleEstimator` - several checkpoints, mean and interval in decades
  (``ensemble.py``).
* :func:`export_onnx` - ONNX export with a parity check (``export.py``);
  :class:`OnnxEstimator` runs the exported file with onnxruntime (``onnx.py``).
* :func:`export_safetensors` - weights + ``config.json`` + a model card in one directory
  (``export.py``, format in ``pretrained.py``), loaded by
  ``ComplianceEstimator.from_pretrained``.
* :func:`predict_path` - a store, raw grasp directory or video -> predictions
  (``predict.py``, reading with ``sources.py``; the ``predict`` command).
* :func:`live_estimates` - a sensor (``tactile_compliance.acquisition``) plus readings
  through the streaming estimator (``live.py``; the ``live`` command).

See ``docs/inference.md``.
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
