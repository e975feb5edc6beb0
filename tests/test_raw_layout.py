"""The raw layout has one reader and one writer (data/raw_layout.py), used by the importer,
``predict``, the generator and ``record``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tactile_compliance.data import raw_layout, yuan
from tactile_compliance.data.store import frames_from_uint8
from tactile_compliance.inference.sources import read_grasp_dir, read_source


@pytest.mark.parametrize("suffix", raw_layout.VIDEO_SUFFIXES)
def test_a_video_import_accepts_predict_accepts(tmp_path: Path, suffix: str) -> None:
    """`import yuan` and `predict` take the same video files: both try to decode them."""
    video = tmp_path / f"BASIC_34_2{suffix.upper()}"
    video.write_bytes(b"not a video")
    assert yuan.VIDEO_NAME.match(video.name)
    with pytest.raises(ValueError, match=r"cannot open video|no decodable frames"):
        read_source(video)


def test_predict_refuses_what_import_refuses(tmp_path: Path) -> None:
    text = tmp_path / "BASIC_34_2.txt"
    text.write_text("x")
    assert not yuan.VIDEO_NAME.match(text.name)
    with pytest.raises(ValueError, match="not a store, grasp directory or video"):
        read_source(text)


def _sample(rng: np.random.Generator) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    frames = (rng.integers(100, 156, size=(3, 6, 8, 3)) / 255.0).astype(np.float32)
    depth = rng.uniform(0.0, 2.0, size=(3, 6, 8)).astype(np.float32)
    return {"markerless": (frames, depth), "markers": (frames[..., ::-1] * 0.9, depth / 2)}


def test_writer_then_reader_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    fingers = _sample(rng)
    forces = np.array([5.0, 7.5, 9.8])
    widths = np.array([0.031, 0.030, 0.029])
    object_dir = tmp_path / "foam"
    object_dir.mkdir()
    raw_layout.write_metadata(object_dir, "foam", 4.2e4, "Foam", "Cube", (12.0, None, None))
    directory = raw_layout.augmentation_dir(raw_layout.grasp_dir(object_dir, 2), 1)
    raw_layout.write_sample(directory, fingers, forces, widths, (3.0e4, float("nan")))

    assert raw_layout.sample_dirs(object_dir) == [(2, 1, directory)]
    metadata = raw_layout.read_metadata(object_dir)
    assert metadata["youngs_modulus"] == 4.2e4 and metadata["shore_00_hardness"] == 12.0
    # A failed fit has no file, as in the public dataset; the reader gives NaN.
    assert not (directory / raw_layout.ESTIMATE_FILES[1]).exists()
    elastic, hertz = (raw_layout.load_estimate(directory, n) for n in raw_layout.ESTIMATE_FILES)
    assert elastic == 3.0e4 and np.isnan(hertz)
    np.testing.assert_array_equal(raw_layout.load_vector(directory, raw_layout.FORCES_FILE), forces)
    np.testing.assert_array_equal(raw_layout.load_vector(directory, raw_layout.WIDTHS_FILE), widths)
    for finger, (images, depth) in fingers.items():
        image_file, depth_file = raw_layout.FINGER_FILES[finger]
        # The files hold BGR; the reader returns RGB.
        rgb = raw_layout.load_frames(directory, image_file, (6, 8))
        np.testing.assert_allclose(rgb, images[..., ::-1], atol=1e-6)
        maxima, maps = raw_layout.load_depth(directory, depth_file, (6, 8))
        np.testing.assert_allclose(maxima, depth.reshape(3, -1).max(axis=1), rtol=1e-6)
        np.testing.assert_allclose(maps, depth, rtol=1e-6)

    # predict reads the same directory through the same reader.
    batch = read_grasp_dir(object_dir)
    assert list(batch.rows["finger"]) == ["markerless", "markers"]
    assert batch.rows["modulus_pa"].tolist() == [4.2e4, 4.2e4]
    expected = fingers["markerless"][0][..., ::-1]
    np.testing.assert_allclose(frames_from_uint8(batch.frames[0]), expected, atol=1 / 255)
    np.testing.assert_array_equal(batch.force_n[0], forces)


def test_writer_refuses_an_unknown_dtype(tmp_path: Path) -> None:
    fingers = _sample(np.random.default_rng(1))
    with pytest.raises(ValueError, match="dtype must be one of"):
        raw_layout.write_sample(tmp_path / "s", fingers, np.ones(3), np.ones(3), (1.0, 1.0), "int8")
    assert not (tmp_path / "s").exists()
