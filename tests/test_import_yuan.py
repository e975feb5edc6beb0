"""Importer for the Shore-hardness press videos."""

from __future__ import annotations

import numpy as np
import pytest

from helpers import write_level_video
from tactile_compliance.data.import_report import DataImportError
from tactile_compliance.data.store import GraspStore
from tactile_compliance.data.yuan import import_yuan, select_press_frames


def test_frame_selection_first_midway_brightest():
    levels = np.array([10, 20, 40, 90, 60, 30], dtype=np.uint8)
    frames = np.broadcast_to(levels[:, None, None, None], (6, 2, 2, 3))
    assert select_press_frames(frames) == (0, 1, 3)


def _coloured(levels_rgb: list[tuple[int, int, int]]) -> np.ndarray:
    """(T, 4, 4, 3) uint8 RGB frames, frame t filled with ``levels_rgb[t]``."""
    return np.ascontiguousarray(
        np.broadcast_to(
            np.array(levels_rgb, np.uint8)[:, None, None, :], (len(levels_rgb), 4, 4, 3)
        )
    )


def test_brightest_frame_is_opencvs_weighted_grey_not_the_channel_mean():
    # Pure green 100: channel mean 33.3, grey 0.587 * 100 = 58.7.
    # Pure blue 200:  channel mean 66.7, grey 0.114 * 200 = 22.8.
    frames = _coloured([(0, 0, 0), (0, 0, 0), (0, 40, 0), (0, 100, 0), (0, 0, 90), (0, 0, 200)])
    grey = [0.299 * r + 0.587 * g + 0.114 * b for r, g, b in frames[:, 0, 0].astype(float)]
    assert int(np.argmax(grey)) == 3
    assert int(np.argmax(frames.reshape(6, -1).mean(axis=1))) == 5  # the mean disagrees
    assert select_press_frames(frames) == (0, 1, 3)


def test_brightest_frame_reads_the_frames_as_rgb():
    # Red 100 (grey 29.9) against blue 240 (grey 27.4): read as BGR, the red frame would
    # weigh 0.114 * 100 = 11.4 and the blue one 0.299 * 240 = 71.8.
    frames = _coloured([(0, 0, 0), (100, 0, 0), (0, 0, 0), (0, 0, 240)])
    assert select_press_frames(frames) == (0, 0, 1)
    assert select_press_frames(frames[:, :, :, ::-1]) == (0, 1, 3)  # the same frames in BGR


def test_import_labels_and_frames(tmp_path):
    src = tmp_path / "videos"
    src.mkdir()
    write_level_video(src / "BASIC_60_1.avi", [20, 60, 100, 140, 120, 80])
    write_level_video(src / "HEMI_SPHERE_08_2.avi", [30, 30, 200, 40])
    report = import_yuan(src, tmp_path / "store", progress=False)
    assert report.problems == [] and report.samples_imported == 2
    store = GraspStore.open(tmp_path / "store")
    samples = store.samples.set_index("object")
    # Larson: E[MPa] = 0.0037 exp(0.0718 S00); S00 = 60 -> 0.2748 MPa.
    assert samples.loc["BASIC_60", "modulus_pa"] == pytest.approx(0.0037e6 * np.exp(0.0718 * 60))
    assert samples.loc["BASIC_60", "modulus_pa"] == pytest.approx(2.748e5, rel=1e-3)
    assert samples.loc["HEMI_SPHERE_08", "shape"] == "HEMI_SPHERE"
    assert samples.loc["HEMI_SPHERE_08", "grasp"] == 2
    assert samples["material"].eq("Silicone").all()
    assert samples["force_n_0"].isna().all() and samples["hertz_estimate_pa"].isna().all()
    # BASIC_60: frames 0 (first), 1 (midway), 3 (brightest); red/green follow the level.
    frames = store.frames[int(samples.loc["BASIC_60", "sample_id"])]
    red = frames[..., 0].reshape(3, -1).mean(axis=1)
    blue = frames[..., 2].reshape(3, -1).mean(axis=1)
    assert np.allclose(red, [20, 60, 140], atol=4)  # MJPG is lossy
    assert np.allclose(blue, 10, atol=4)
    assert store.header.creation_parameters["frame_kind"] == "raw"


def test_bad_videos_are_reported(tmp_path):
    src = tmp_path / "videos"
    src.mkdir()
    write_level_video(src / "BASIC_60_1.avi", [20, 60, 100])
    (src / "BASIC_70_1.avi").write_bytes(b"not a video at all")
    write_level_video(src / "notes.avi", [1, 2, 3])
    report = import_yuan(src, tmp_path / "store", progress=False, image_size=(12, 16))
    reasons = dict(report.reasons())
    assert reasons == {"unreadable video": 1, "unexpected file name": 1}
    assert GraspStore.open(tmp_path / "store").frames.shape == (1, 3, 12, 16, 3)
    with pytest.raises(DataImportError, match="unreadable video"):
        import_yuan(src, tmp_path / "store2", progress=False, strict=True)
    with pytest.raises(FileExistsError):
        import_yuan(src, tmp_path / "store", progress=False)


def test_yuan_preset_trains_as_published_for_this_data():
    """Up to 1000 epochs with early stopping, flips as the only augmentation."""
    import torch

    from tactile_compliance.config import load_config
    from tactile_compliance.data.augment import GraspAugmentation
    from tactile_compliance.training.experiment_file import expand_experiment, load_experiment

    cfg = load_config("yuan")
    assert cfg.training.max_epochs == 1000 and cfg.training.patience == 30
    cells = expand_experiment(load_experiment("new-dataset"))
    assert {c.cfg.training.max_epochs for c in cells} == {1000}
    assert all(c.cfg.augmentation == cfg.augmentation for c in cells)
    augment = GraspAugmentation.from_config(cfg.augmentation, seed=0).train()
    frames = torch.rand(16, 3, 3, 5, 7)
    out = augment(frames)
    flips = {"none": (), "h": (-1,), "v": (-2,), "hv": (-2, -1)}
    seen = set()
    for before, after in zip(frames, out, strict=True):
        # Every sample is a flip of itself (the same one for its 3 frames), nothing else.
        matches = [name for name, dims in flips.items() if torch.equal(after, before.flip(dims))]
        assert matches, "a sample was changed by more than a flip"
        seen.add(matches[0])
    assert len(seen) >= 3  # 16 samples, 4 equally likely flips
