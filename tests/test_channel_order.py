"""Channel order end to end: a red pixel in the dataset's BGR pickle reaches the model as
channel 0 (R), normalised with the red channel's statistics.

The published statistics are per channel of the dataset's pickles as they are, B, G, R
(mfkuhlmann/youngs-modulus-estimation normalises the unflipped arrays, which Burgess et
al. wrote from OpenCV frames). Our importer flips frames to RGB, so the constants must be
reversed; otherwise red would be normalised with the blue statistics.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from burgess_tree import dump, write_tree
from tactile_compliance.config import ExperimentConfig, load_config
from tactile_compliance.data.burgess import import_burgess
from tactile_compliance.data.dataset import GraspDataset, prepare_frames
from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.data.store import GraspStore

# The published statistics exactly as the published code writes them (B, G, R).
PUBLISHED_MEAN_BGR = (0.49638007, 0.49770336, 0.49385751)
PUBLISHED_STD_BGR = (0.04634926, 0.06181679, 0.07152624)
# Reversed by hand: the store's R, G, B.
MEAN_RGB = (0.49385751, 0.49770336, 0.49638007)
STD_RGB = (0.07152624, 0.06181679, 0.04634926)

SIZE = (6, 8)
RED, BLUE = 2, 0  # channel of red and blue in the OpenCV (BGR) pickle


def pure_red_bgr() -> np.ndarray:
    """Three difference frames (3, H, W, 3), BGR: B = G = 0 and R = 1 (255 of 255)."""
    frames = np.zeros((3, *SIZE, 3))
    frames[..., RED] = 1.0
    return frames


@pytest.fixture(scope="module")
def red_store(tmp_path_factory: pytest.TempPathFactory) -> GraspStore:
    root = tmp_path_factory.mktemp("channel_order")
    objects = {"red_block": (1.0e6, "Rubber", "Rectangular")}
    write_tree(root / "src", objects=objects, grasps=1, augmentations=1, size=SIZE)
    aug_dir = root / "src" / "red_block" / "grasp=0" / "augmentation=0"
    dump(aug_dir / "RGB.pkl", pure_red_bgr())
    report = import_burgess(root / "src", root / "store", fingers="markerless", progress=False)
    assert report.problems == [] and report.samples_imported == 1
    return GraspStore.open(root / "store")


def test_the_constants_are_the_published_ones_reversed() -> None:
    constants = NormalisationConstants()
    assert constants.image_mean == MEAN_RGB == PUBLISHED_MEAN_BGR[::-1]
    assert constants.image_std == STD_RGB == PUBLISHED_STD_BGR[::-1]
    # The experiment configuration's defaults are the same.
    assert ExperimentConfig().normalisation_constants().image_mean == MEAN_RGB


def test_the_shipped_preset_uses_the_store_order() -> None:
    # configs/default.yaml spells the statistics out; they must be the RGB ones too.
    constants = load_config("default").normalisation_constants()
    assert constants.image_mean == pytest.approx(MEAN_RGB, abs=5e-6)
    assert constants.image_std == pytest.approx(STD_RGB, abs=5e-6)


def test_red_is_stored_in_channel_0(red_store: GraspStore) -> None:
    frames = red_store.load_frames(0)[0]  # (3, H, W, 3) RGB, decoded
    assert red_store.header.channel_order == "RGB"
    np.testing.assert_allclose(frames[..., 0], 255.5 / 255, rtol=1e-6)  # R: full scale
    np.testing.assert_allclose(frames[..., 1:], 0.5 / 255, rtol=1e-6)  # G, B: zero


def test_red_reaches_the_model_normalised_with_the_red_statistics(red_store: GraspStore) -> None:
    constants = NormalisationConstants()
    dataset = GraspDataset(red_store, [0], constants, "Image")
    batch = dataset.batch([0])
    x = prepare_frames(batch["frames"], constants)  # (1, 3 frames, 3 channels, H, W)
    assert x.shape == (1, 3, 3, *SIZE)
    # The store decodes the pickle's R = 1.0 as (255 + 0.5) / 255 and B = G = 0 as 0.5 / 255.
    red, zero = 255.5 / 255, 0.5 / 255
    expected_red = (red - PUBLISHED_MEAN_BGR[RED]) / PUBLISHED_STD_BGR[RED]
    expected_green = (zero - PUBLISHED_MEAN_BGR[1]) / PUBLISHED_STD_BGR[1]
    expected_blue = (zero - PUBLISHED_MEAN_BGR[BLUE]) / PUBLISHED_STD_BGR[BLUE]
    for channel, expected in enumerate((expected_red, expected_green, expected_blue)):
        torch.testing.assert_close(
            x[:, :, channel], torch.full_like(x[:, :, channel], expected), rtol=1e-5, atol=1e-5
        )
    # The published tuple used as if it were RGB normalises red with the blue statistics
    # (about 10.9 instead of 7.1): the test tells the two apart.
    wrong = (red - PUBLISHED_MEAN_BGR[0]) / PUBLISHED_STD_BGR[0]
    assert abs(wrong - expected_red) > 1.0


def test_a_checkpoint_keeps_the_statistics_it_was_trained_with() -> None:
    # A checkpoint written before the fix stores the published tuple in BGR order; reading
    # it back must give those values, not the new defaults.
    stored = NormalisationConstants().to_dict()
    stored["image_mean"] = list(PUBLISHED_MEAN_BGR)
    stored["image_std"] = list(PUBLISHED_STD_BGR)
    restored = NormalisationConstants.from_dict(stored)
    assert restored.image_mean == PUBLISHED_MEAN_BGR
    assert restored.image_std == PUBLISHED_STD_BGR
    assert restored != NormalisationConstants()
