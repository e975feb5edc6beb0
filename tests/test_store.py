"""GraspStore: round trip, memory mapping, atomic writes, clear errors."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

from tactile_compliance.data.store import (
    FRAMES_FILE,
    HEADER_FILE,
    MAX_DIFFERENCE_LEVEL,
    MIN_DIFFERENCE_LEVEL,
    SAMPLES_FILE,
    GraspStore,
    StoreError,
    encode_frames,
    frames_from_uint8,
    frames_to_uint8,
    store_problems,
    validate_samples,
)
from tactile_compliance.data.store_writer import GraspStoreWriter


def _row(i: int) -> dict:
    return {
        "object": f"obj_{i % 2}",
        "grasp": i,
        "augmentation": 0,
        "finger": "markerless",
        "material": "Rubber",
        "shape": "Sphere",
        "modulus_pa": 1e5 * (i + 1),
        "force_n_0": 5.0,
        "force_n_1": 20.0,
        "force_n_2": 50.0 + i,
        "width_m_0": 0.05,
        "width_m_1": 0.049,
        "width_m_2": 0.048,
        "source_path": f"x/{i}",
    }


def test_round_trip_values_and_memmap(tmp_path):
    rng = np.random.default_rng(0)
    frames = [rng.uniform(0, 1, (3, 4, 5, 3)).astype(np.float32) for _ in range(3)]
    with GraspStoreWriter(tmp_path / "s", image_size=(4, 5), source="test") as writer:
        for i, f in enumerate(frames):
            assert writer.append(f, _row(i)) == i
    store = GraspStore.open(tmp_path / "s")
    assert len(store) == 3
    assert isinstance(store.frames, np.memmap)
    assert store.frames.shape == (3, 3, 4, 5, 3)
    # Quantisation error is at most half a grey level.
    loaded = store.load_frames([2, 0])
    assert np.abs(loaded[0] - frames[2]).max() <= 0.5 / 255 + 1e-7
    assert np.abs(loaded[1] - frames[0]).max() <= 0.5 / 255 + 1e-7
    assert store.forces_n()[1].tolist() == [5.0, 20.0, 51.0]
    assert np.isnan(store.estimates_pa()).all()  # not given -> NaN
    assert store.samples["sample_id"].tolist() == [0, 1, 2]
    summary = store.summary()
    assert summary["num_objects"] == 2 and summary["materials"] == {"Rubber": 3}
    assert summary["modulus_pa_min"] == 1e5 and summary["modulus_pa_max"] == 3e5


def test_frames_to_uint8_floors_and_clips():
    x = np.array([-0.1, 0.0, 0.5, 1.0, 1.2, 0.25 / 255, 0.999 / 255])
    assert frames_to_uint8(x).tolist() == [0, 0, 127, 255, 255, 0, 0]


def test_recording_pipeline_values_survive_exactly():
    # Real difference images are k / 255 + 0.5 (uint8 frame - uint8 blurred reference):
    # every level must survive the store, none may merge with its neighbour.
    k = np.arange(-127, 128)
    for dtype in (np.float64, np.float32, np.float16):
        x = (k / 255 + 0.5).astype(dtype)
        encoded = frames_to_uint8(x)
        assert len(np.unique(encoded)) == len(k), dtype
        assert np.abs(frames_from_uint8(encoded) - (k / 255 + 0.5)).max() < 1e-6


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_encoding_holds_minus_127_to_plus_128_levels_and_counts_the_rest(dtype):
    # Differences of k grey levels (x = k / 255 + 0.5): -127..+128 fit in uint8, the
    # three beyond each end are clipped to the end and counted.
    k = np.arange(-130, 132)
    x = (k / 255 + 0.5).astype(dtype)
    encoded, clipped = encode_frames(x)
    assert clipped == 6
    decoded_levels = np.round((frames_from_uint8(encoded) - 0.5) * 255).astype(int)
    inside = (k >= MIN_DIFFERENCE_LEVEL) & (k <= MAX_DIFFERENCE_LEVEL)
    assert (MIN_DIFFERENCE_LEVEL, MAX_DIFFERENCE_LEVEL) == (-127, 128)
    assert np.array_equal(decoded_levels[inside], k[inside])
    assert np.array_equal(decoded_levels[~inside], np.clip(k[~inside], -127, 128))
    # Any float below 0 or from 1 + 1/255 up is clipped; uint8 never is.
    assert encode_frames(np.array([-1e-9, 0.0, 1.0 + 0.99 / 255, 1.0 + 1 / 255]))[1] == 2
    assert encode_frames(np.array([0, 255], dtype=np.uint8))[1] == 0


def test_writer_counts_clipped_frame_values(tmp_path):
    frames = np.full((3, 4, 5, 3), 0.5, dtype=np.float32)
    saturated = frames.copy()
    saturated[0, 0, 0, 0] = 1.004  # a few saturated pixels, allowed by the frame rule
    saturated[2, 3, 4, 2] = -0.003
    with GraspStoreWriter(tmp_path / "s", image_size=(4, 5), source="test") as writer:
        writer.append(frames, _row(0))
        writer.append(saturated, _row(1))
        writer.append(frames.astype(np.float64), _row(2))
        assert writer.frame_values == 3 * frames.size
        assert writer.clipped_frame_values == 2
        assert writer.samples_with_clipped_frames == 1


def test_failed_write_leaves_nothing(tmp_path):
    with pytest.raises(RuntimeError), GraspStoreWriter(tmp_path / "s", (4, 5), "test") as writer:
        writer.append(np.zeros((3, 4, 5, 3)), _row(0))
        raise RuntimeError("interrupted")
    assert not (tmp_path / "s").exists()
    assert list(tmp_path.iterdir()) == []  # the temporary directory is gone too


def test_refuses_existing_without_overwrite_and_replaces_with(tmp_path):
    with GraspStoreWriter(tmp_path / "s", (4, 5), "first") as writer:
        writer.append(np.zeros((3, 4, 5, 3)), _row(0))
    with pytest.raises(FileExistsError, match="--overwrite"):
        GraspStoreWriter(tmp_path / "s", (4, 5), "second")
    with GraspStoreWriter(tmp_path / "s", (4, 5), "second", overwrite=True) as writer:
        writer.append(np.zeros((3, 4, 5, 3)), _row(0))
        writer.append(np.zeros((3, 4, 5, 3)), _row(1))
    store = GraspStore.open(tmp_path / "s")
    assert store.header.source == "second" and len(store) == 2


def test_append_validates(tmp_path):
    with GraspStoreWriter(tmp_path / "s", (4, 5), "test") as writer:
        with pytest.raises(ValueError, match="shape"):
            writer.append(np.zeros((3, 5, 4, 3)), _row(0))
        with pytest.raises(ValueError, match="NaN"):
            writer.append(np.full((3, 4, 5, 3), np.nan), _row(0))
        with pytest.raises(ValueError, match="unknown sample fields"):
            writer.append(np.zeros((3, 4, 5, 3)), {**_row(0), "colour": "red"})
        writer.append(np.zeros((3, 4, 5, 3)), _row(0))


def test_open_rejects_incomplete_store(tmp_path):
    with GraspStoreWriter(tmp_path / "s", (4, 5), "test") as writer:
        writer.append(np.zeros((3, 4, 5, 3)), _row(0))
    with pytest.raises(StoreError, match="no such store"):
        GraspStore.open(tmp_path / "missing")
    # A truncated frames file is detected, not silently read.
    frames_path = tmp_path / "s" / FRAMES_FILE
    frames_path.write_bytes(frames_path.read_bytes()[:-1])
    with pytest.raises(StoreError, match="expected 180 bytes"):
        GraspStore.open(tmp_path / "s")
    (tmp_path / "s" / HEADER_FILE).unlink()
    with pytest.raises(StoreError, match="not a GraspStore"):
        GraspStore.open(tmp_path / "s")


def test_header_records_format(tmp_path):
    with GraspStoreWriter(tmp_path / "s", (4, 5), "test", {"seed": 3}) as writer:
        writer.append(np.zeros((3, 4, 5, 3)), _row(0))
    header = json.loads((tmp_path / "s" / HEADER_FILE).read_text())
    assert header["channel_order"] == "RGB"
    assert header["image_size"] == [4, 5]
    assert header["creation_parameters"] == {"seed": 3}
    assert header["format_version"] == 1


@pytest.mark.parametrize(
    ("version", "match"),
    [(0, "format_version 0 is a pre-release format"), (2, "format_version 2 is newer")],
)
def test_one_store_format_is_read(tmp_path, version, match):
    """Pre-release formats are refused in one line naming the version, not read."""
    with GraspStoreWriter(tmp_path / "s", (4, 5), "test") as writer:
        writer.append(np.zeros((3, 4, 5, 3)), _row(0))
    header = json.loads((tmp_path / "s" / HEADER_FILE).read_text())
    header["format_version"] = version
    (tmp_path / "s" / HEADER_FILE).write_text(json.dumps(header))
    with pytest.raises(StoreError, match=match) as caught:
        GraspStore.open(tmp_path / "s")
    assert "\n" not in str(caught.value) and "reads format 1 only" in str(caught.value)


def test_a_header_without_its_shape_check_is_refused(tmp_path):
    with GraspStoreWriter(tmp_path / "s", (4, 5), "test") as writer:
        writer.append(np.zeros((3, 4, 5, 3)), _row(0))
    header = json.loads((tmp_path / "s" / HEADER_FILE).read_text())
    del header["frame_shape_sha256"]
    (tmp_path / "s" / HEADER_FILE).write_text(json.dumps(header))
    with pytest.raises(StoreError, match="frame_shape_sha256"):
        GraspStore.open(tmp_path / "s")


def test_read_sample_matches_memmap_and_survives_pickling(tmp_path):
    import pickle

    rng = np.random.default_rng(1)
    with GraspStoreWriter(tmp_path / "s", (4, 5), "test") as writer:
        for i in range(3):
            writer.append(rng.integers(0, 256, (3, 4, 5, 3), dtype=np.uint8), _row(i))
    store = GraspStore.open(tmp_path / "s")
    for i in range(3):
        assert np.array_equal(store.read_sample(i), store.frames[i])
    payload = pickle.dumps(store)  # what a spawned DataLoader worker receives
    assert np.asarray(store.frames).tobytes() not in payload  # reopened, not copied
    clone = pickle.loads(payload)
    assert np.array_equal(clone.frames[1], store.frames[1])
    assert np.array_equal(clone.read_sample(2), store.frames[2])
    with pytest.raises(IndexError):
        store.read_sample(3)


def test_read_block_and_load_frames_match_the_memmap(tmp_path):
    """pread-based readers return exactly the memmap's bytes, in the requested order."""
    from toy_store import make_toy_store

    store = make_toy_store(tmp_path / "store")
    n = len(store)
    assert np.array_equal(store.read_block(2, 7), np.asarray(store.frames[2:7]))
    assert store.read_block(3, 3).shape == (0, *store.frames.shape[1:])
    ids = [5, 1, 5, n - 1]
    expected = (np.asarray(store.frames[ids]).astype(np.float32) + 0.5) / 255.0
    assert np.array_equal(store.load_frames(ids), expected)
    with pytest.raises(IndexError):
        store.read_block(0, n + 1)


def test_store_frames_reads_like_the_memmap(tmp_path):
    from tactile_compliance.inference.sources import StoreFrames
    from toy_store import make_toy_store

    store = make_toy_store(tmp_path / "store")
    frames = StoreFrames(store)
    assert len(frames) == len(store) and frames.shape == store.frames.shape
    assert np.array_equal(frames[[4, 0, 4]], np.asarray(store.frames[[4, 0, 4]]))
    assert np.array_equal(frames[1:5], np.asarray(store.frames[1:5]))


def _store_with_table(tmp_path, edit):
    """A 6-sample store whose samples.parquet is then edited (as a buggy tool might)."""
    with GraspStoreWriter(tmp_path / "s", (4, 5), "test") as writer:
        for i in range(6):
            writer.append(np.zeros((3, 4, 5, 3)), _row(i))
    table = pd.read_parquet(tmp_path / "s" / SAMPLES_FILE)
    table = edit(table)
    table.to_parquet(tmp_path / "s" / SAMPLES_FILE, index=False)
    return tmp_path / "s"


def _set(column, rows, value):
    def edit(table):
        table[column] = table[column].astype(str if isinstance(value, str) else float)
        table.loc[rows, column] = value
        return table

    return edit


@pytest.mark.parametrize(
    ("edit", "expected"),
    [
        (_set("modulus_pa", [1, 4], np.nan), r"modulus_pa .* 2 bad row\(s\): row 1: nan, row 4"),
        (_set("modulus_pa", [3], -5.0), r"modulus_pa must be a finite number > 0 Pa.*row 3: -5"),
        (_set("modulus_pa", [0], 0.0), r"modulus_pa.*row 0: 0\.0"),
        (_set("modulus_pa", [2], np.inf), r"modulus_pa.*row 2: inf"),
        (_set("modulus_pa", [5], "soft"), r"modulus_pa.*row 5: 'soft'"),
        (lambda t: t.drop(columns=["modulus_pa", "object"]), r"missing columns"),
        (_set("sample_id", [2], 1), r"sample_id has 1 duplicated value.*row 2: 1"),
        (lambda t: t.iloc[::-1], r"sample_id must equal the row number.*row 0: 5"),
    ],
)
def test_open_rejects_bad_tables(tmp_path, edit, expected):
    path = _store_with_table(tmp_path, edit)
    with pytest.raises(StoreError, match=expected):
        GraspStore.open(path)
    problems = store_problems(path)
    assert len(problems) == 1 and problems[0]
    if "missing" not in expected:
        # validate=False opens it anyway (to inspect); validate_samples says the same.
        store = GraspStore.open(path, validate=False)
        assert validate_samples(store.samples) == problems


def test_valid_store_has_no_problems(tmp_path):
    path = _store_with_table(tmp_path, lambda t: t)
    assert store_problems(path) == [] and validate_samples(GraspStore.open(path).samples) == []
    assert store_problems(tmp_path / "missing") == [
        f"{tmp_path / 'missing'}: no such store directory"
    ]


def test_info_reports_a_bad_label(tmp_path):
    from typer.testing import CliRunner

    from tactile_compliance.cli import app

    path = _store_with_table(tmp_path, _set("modulus_pa", [2], np.nan))
    result = CliRunner().invoke(app, ["info", str(path)])
    assert result.exit_code != 0 and "modulus_pa" in result.output and "row 2" in result.output


def test_writer_refuses_bad_labels_and_text(tmp_path):
    with GraspStoreWriter(tmp_path / "s", (4, 5), "test") as writer:
        for bad in (np.nan, -1.0, 0.0, np.inf, None):
            with pytest.raises(ValueError, match="modulus_pa must be a finite number > 0"):
                writer.append(np.zeros((3, 4, 5, 3)), {**_row(0), "modulus_pa": bad})
        with pytest.raises(ValueError, match="object is not valid UTF-8"):
            writer.append(np.zeros((3, 4, 5, 3)), {**_row(0), "object": "caf\udce9"})
        writer.append(np.zeros((3, 4, 5, 3)), _row(0))
    assert len(GraspStore.open(tmp_path / "s")) == 1
