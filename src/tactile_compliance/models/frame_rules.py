"""The frame-size rules of the built-in models, torch-free: the smallest frame side each
backbone takes and the frame size a model recommends, so that ``train`` can refuse frames
that are too small before torch loads (docs/models.md, "Frame sizes").

The networks take their values from here (``Top10Encoder.min_input_size``,
``VGG16.min_input_size``, ``VggLstm.recommended_image_size``);
``TactileModel.min_image_size`` stays the rule a built model answers, and
tests/test_models.py checks that :func:`min_frame_side` equals it for every built-in model.
"""

from __future__ import annotations

from tactile_compliance.data.inputs import MIN_FRAME_SIDE_PX

__all__ = [
    "RECOMMENDED_FRAME_SIZE",
    "TOP10_KERNELS",
    "TOP10_MIN_INPUT_PX",
    "TOP10_STRIDE",
    "VGG16_MIN_INPUT_PX",
    "min_frame_side",
    "too_small_message",
]

#: Top10NN's per-frame CNN: unpadded convolutions of these kernel sizes, each stride 2.
TOP10_KERNELS = (5, 3, 3, 3, 3)
TOP10_STRIDE = 2


def _conv_stack_min_size(kernels: tuple[int, ...], stride: int) -> int:
    """Smallest input side [px] for which every unpadded convolution still has one output
    pixel: walking backwards from one output pixel, ``n_in = (n_out - 1) * stride + k``."""
    size = 1
    for kernel in reversed(kernels):
        size = (size - 1) * stride + kernel
    return size


#: Top10NN's smallest frame side [px] (65).
TOP10_MIN_INPUT_PX = _conv_stack_min_size(TOP10_KERNELS, TOP10_STRIDE)
#: VGG16's five unpadded 2x2 max-pools: anything below 32 px pools to nothing.
VGG16_MIN_INPUT_PX = 32
#: Backbone minimum [px] of each built-in model with frames (ResNets pad: 1 px).
_BACKBONE_MIN_PX = {"top10nn": TOP10_MIN_INPUT_PX, "vgg_lstm": VGG16_MIN_INPUT_PX, "res_tf": 1}
#: (height, width) px a built-in model resizes frames to when ``data.image_size`` is unset.
RECOMMENDED_FRAME_SIZE: dict[str, tuple[int, int]] = {"vgg_lstm": (224, 224)}


def min_frame_side(model: str) -> int | None:
    """The smallest frame height and width [px] built-in ``model`` takes
    (``MIN_FRAME_SIDE_PX`` or its backbone's minimum, the larger); None for a model this
    module does not know (a frame-free or a program's own model: its built instance
    decides)."""
    backbone = _BACKBONE_MIN_PX.get(model)
    return None if backbone is None else max(MIN_FRAME_SIDE_PX, backbone)


def too_small_message(model: str, minimum: int, origin: str, size: tuple[int, int]) -> str:
    """The one line for frames ``size`` (H, W) px below ``minimum`` px, ``origin`` saying
    where the size came from ("data.image_size is", "the store's frames are"): the text of
    ``runs.config_checks.check_frame_size_early`` and ``training.train.check_frame_size``."""
    height, width = size
    return (
        f"{model} needs frames of at least {minimum}x{minimum} px, but {origin} "
        f"{height}x{width}: set data.image_size to [{max(height, minimum)}, "
        f"{max(width, minimum)}] or larger"
    )
