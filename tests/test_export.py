"""ONNX export: parity with PyTorch (< 1e-4), dynamic batch, inputs per strategy, OnnxEstimator."""

from __future__ import annotations

import numpy as np
import onnx
import pytest
import torch
from torch import nn

from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.inference import (
    ComplianceEstimator,
    OnnxEstimator,
    export_onnx,
    format_export_report,
)
from tactile_compliance.inference.export import _FixedAdaptiveAvgPool2d
from tactile_compliance.inference.onnx import onnx_input_names
from tactile_compliance.models import create_model
from tactile_compliance.runs.checkpoint import save_checkpoint
from tactile_compliance.runs.run_inputs import RunInputs

SMALL_RES_TF = {"num_layers": 1, "embedding_dim": 64, "output_dim": 64}


def _checkpoint(path, name, inputs, image_size, **hparams):
    torch.manual_seed(0)
    model = create_model(name, inputs=inputs, **hparams)
    return save_checkpoint(
        path,
        model,
        run_inputs=RunInputs(image_size, image_size, NormalisationConstants(), model.inputs),
        config={},
        seed=0,
    )


@pytest.mark.parametrize(
    ("name", "inputs", "size", "hparams"),
    [
        ("top10nn", "ALL", (72, 80), {}),
        ("top10nn", "Image", (66, 66), {}),
        ("res_tf", "ImageF", (48, 40), SMALL_RES_TF),
        ("top10nn", "ImageFW", (65, 90), {}),
    ],
)
def test_export_parity_and_inputs_match_the_strategy(tmp_path, name, inputs, size, hparams):
    checkpoint = _checkpoint(tmp_path / "m.pt", name, inputs, size, **hparams)
    report = export_onnx(checkpoint, tmp_path / "m.onnx")
    assert report["parity_ok"] and report["max_abs_diff"] < 1e-4
    names = onnx_input_names(inputs)
    assert list(report["inputs"]) == names
    graph = onnx.load(str(tmp_path / "m.onnx")).graph
    assert [i.name for i in graph.input] == names
    for graph_input in graph.input:  # dynamic batch axis, fixed frame size
        dims = graph_input.type.tensor_type.shape.dim
        assert dims[0].dim_param == "batch"
        if graph_input.name == "frames":
            assert [d.dim_value for d in dims[1:]] == [3, 3, *size]
    assert [o.name for o in graph.output] == ["modulus_normalised"]
    assert "Parity" in format_export_report(report) and "OK" in format_export_report(report)


def test_onnx_estimator_agrees_with_the_pytorch_estimator(tmp_path):
    checkpoint = _checkpoint(tmp_path / "m.pt", "top10nn", "ALL", (72, 72))
    export_onnx(checkpoint, tmp_path / "m.onnx")
    torch_estimator = ComplianceEstimator.from_checkpoint(checkpoint)
    onnx_estimator = OnnxEstimator(tmp_path / "m.onnx")
    assert onnx_estimator.required_inputs == ("frames", "force", "width", "estimates")
    rng = np.random.default_rng(0)
    for batch in (1, 5):  # dynamic batch size at run time
        frames = rng.integers(90, 170, size=(batch, 3, 40, 56, 3), dtype=np.uint8)
        scalars = {
            "force": rng.uniform(5, 60, (batch, 3)),
            "width": rng.uniform(0.03, 0.06, (batch, 3)),
            "estimates": 10 ** rng.uniform(3, 9, (batch, 2)),
        }
        a = torch_estimator.predict(frames, **scalars)
        b = onnx_estimator.predict(frames, **scalars)
        assert np.ptp(a.normalised) > 0 or batch == 1
        np.testing.assert_allclose(b.normalised, a.normalised, atol=1e-4)
    with pytest.raises(ValueError, match="needs `estimates`"):
        onnx_estimator.predict(frames[0], force=[8, 30, 58], width=[0.05, 0.048, 0.046])


def test_export_takes_the_checkpoints_frame_size_and_onnx_estimator_needs_metadata(tmp_path):
    checkpoint = _checkpoint(tmp_path / "m.pt", "top10nn", "Image", (70, 70))
    report = export_onnx(checkpoint, tmp_path / "m.onnx")
    assert report["image_size"] == [70, 70]
    model = onnx.load(str(tmp_path / "m.onnx"))
    del model.metadata_props[:]
    onnx.save(model, str(tmp_path / "bare.onnx"))
    with pytest.raises(ValueError, match="no metadata"):
        OnnxEstimator(tmp_path / "bare.onnx")


@pytest.mark.parametrize(
    ("size_in", "size_out"),
    [((1, 1), (7, 7)), ((2, 3), (7, 7)), ((14, 14), (7, 7)), ((13, 10), (7, 7)), ((9, 20), (4, 3))],
)
def test_fixed_adaptive_pool_equals_torch(size_in, size_out):
    # VGG16's 7x7 pool is exported through this replacement.
    x = torch.randn(4, 5, *size_in)
    expected = nn.AdaptiveAvgPool2d(size_out)(x)
    torch.testing.assert_close(_FixedAdaptiveAvgPool2d(size_in, size_out)(x), expected)


@pytest.mark.slow
def test_vgg_lstm_export_parity(tmp_path):
    # VGG16's fc6 alone has 103 M parameters whatever the frame size: slow and ~540 MB.
    checkpoint = _checkpoint(tmp_path / "m.pt", "vgg_lstm", "ALL", (32, 32), hidden_size=32)
    report = export_onnx(checkpoint, tmp_path / "m.onnx")
    assert report["parity_ok"] and report["max_abs_diff"] < 1e-4
