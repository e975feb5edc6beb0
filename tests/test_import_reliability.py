"""Imports that must not destroy, leak or abort: --overwrite guards, bad files, full disks,
the frame size, oversized pickles, kills and leftovers, file modes."""

from __future__ import annotations

import errno
import json
import os
import pickle
import signal
import subprocess
import sys
import textwrap
import tracemalloc
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest

from burgess_tree import dump, write_tree
from helpers import write_level_video
from tactile_compliance.data import store as store_module
from tactile_compliance.data import store_writer
from tactile_compliance.data.burgess import import_burgess
from tactile_compliance.data.import_report import DataImportError, import_paths
from tactile_compliance.data.store import GraspStore
from tactile_compliance.data.store_writer import GraspStoreWriter
from tactile_compliance.data.yuan import import_yuan

REPO_ROOT = Path(__file__).resolve().parents[1]


def _import(src, out, **kwargs):
    return import_burgess(src, out, progress=False, **kwargs)


def _snapshot(root: Path) -> dict[str, object]:
    """Every path under ``root`` (hidden ones too) with its bytes, or "dir"."""
    found: dict[str, object] = {}
    for path in sorted(root.rglob("*")):
        key = str(path.relative_to(root))
        if path.is_symlink():
            found[key] = f"link to {os.readlink(path)}"
        else:
            found[key] = "dir" if path.is_dir() else path.read_bytes()
    return found


def _dead_pid() -> int:
    process = subprocess.Popen([sys.executable, "-c", "pass"])
    process.wait()
    return process.pid


# ----------------------------------------------------------------------------- 1 --overwrite
def test_overwrite_refuses_a_directory_that_is_not_a_store(tmp_path):
    write_tree(tmp_path / "src", grasps=1, augmentations=1)
    home = tmp_path / "home"
    (home / "thesis").mkdir(parents=True)
    (home / "thesis" / "chapter1.tex").write_text("precious")
    (home / ".bashrc").write_text("export X=1")
    before = _snapshot(tmp_path)
    with pytest.raises(DataImportError, match="not a GraspStore") as caught:
        _import(tmp_path / "src", home, overwrite=True)
    assert str(home) in str(caught.value)
    assert _snapshot(tmp_path) == before  # nothing deleted, nothing added


def test_overwrite_refuses_a_file_and_a_symlink(tmp_path):
    write_tree(tmp_path / "src", grasps=1, augmentations=1)
    (tmp_path / "notes.txt").write_text("keep me")
    _import(tmp_path / "src", tmp_path / "store")
    (tmp_path / "link").symlink_to(tmp_path / "store")
    before = _snapshot(tmp_path)
    for out in (tmp_path / "notes.txt", tmp_path / "link"):
        with pytest.raises(DataImportError, match=str(out)):
            _import(tmp_path / "src", out, overwrite=True)
    assert _snapshot(tmp_path) == before


def test_overwrite_replaces_stores_old_and_new(tmp_path):
    write_tree(tmp_path / "src", grasps=1, augmentations=1)
    _import(tmp_path / "src", tmp_path / "store", fingers="markerless")
    assert (tmp_path / "store" / store_module.STORE_MARKER).is_file()
    _import(tmp_path / "src", tmp_path / "store", overwrite=True)
    assert len(GraspStore.open(tmp_path / "store")) == 6
    assert sorted(p.name for p in tmp_path.iterdir()) == ["src", "store"]
    # No version wrote a store without its marker: such a directory is not replaced.
    (tmp_path / "store" / store_module.STORE_MARKER).unlink()
    with pytest.raises(DataImportError, match="not a GraspStore"):
        _import(tmp_path / "src", tmp_path / "store", fingers="markers", overwrite=True)
    assert len(GraspStore.open(tmp_path / "store")) == 6


def test_out_and_source_must_not_contain_each_other(tmp_path):
    from tactile_compliance.data.import_report import ImportPathError

    src = tmp_path / "src"
    write_tree(src, grasps=1, augmentations=1)
    before = _snapshot(tmp_path)
    for out in (src, src / "store", src / "foam_block"):
        with pytest.raises(ImportPathError, match="inside the source directory"):
            _import(src, out, overwrite=True)
    assert _snapshot(tmp_path) == before
    # The source inside --out: --overwrite would delete the data being imported.
    _import(src, tmp_path / "store")
    nested = tmp_path / "store" / "raw"
    write_tree(nested, grasps=1, augmentations=1)
    before = _snapshot(tmp_path)
    with pytest.raises(ImportPathError, match="inside --out"):
        _import(nested, tmp_path / "store", overwrite=True)
    assert _snapshot(tmp_path) == before
    assert import_paths(src, tmp_path / "other", False) == (src, tmp_path / "other")


def test_writer_refuses_to_replace_a_non_store(tmp_path):
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "data.csv").write_text("1,2")
    before = _snapshot(tmp_path)
    with pytest.raises(store_module.StoreError, match="not a GraspStore"):
        GraspStoreWriter(tmp_path / "out", (4, 5), "test", overwrite=True)
    assert _snapshot(tmp_path) == before


# ----------------------------------------------------------------------- 3 bad files, disks
def test_string_dtype_pickles_are_skipped_and_reported(tmp_path):
    write_tree(tmp_path / "src")
    aug = tmp_path / "src" / "foam_block" / "grasp=0" / "augmentation=0"
    dump(aug / "forces.pkl", np.array(["a", "b", "c"]))
    dump(aug.parent / "augmentation=1" / "hertz_estimate.pkl", np.array("1e5"))
    dump(aug.parent.parent / "grasp=1" / "augmentation=0" / "RGB.pkl", np.full((3, 12, 16, 3), "x"))
    report = _import(tmp_path / "src", tmp_path / "store")
    reasons = [r for _, r in report.problems]
    assert len(reasons) == 3 and all(r.startswith("wrong dtype") for r in reasons), reasons
    assert len(GraspStore.open(tmp_path / "store")) == 24 - 2 - 2 - 1


def test_non_utf8_names_are_skipped_and_reported(tmp_path):
    src = tmp_path / "src"
    write_tree(src, grasps=1, augmentations=1)
    bad_name = os.fsdecode(b"caf\xe9_cup")
    os.rename(src / "rubber_ball", src / bad_name)
    meta = src / "steel_rod" / "metadata.json"
    meta.write_text(json.dumps({"youngs_modulus": 2e11, "material": "Met\udc80al"}))
    report = _import(src, tmp_path / "store")
    assert report.reasons() == {"invalid name": 1, "invalid metadata.json": 1}
    assert len(GraspStore.open(tmp_path / "store")) == 2
    # The report itself can be printed and saved.
    report.format().encode("utf-8")
    json.dumps(report.to_dict(), ensure_ascii=False).encode("utf-8")


@pytest.mark.parametrize("content", [b"", b"\xff\xfe\x00garbage", b"Label,Shape\n"])
def test_unreadable_object_table_is_one_clear_error(tmp_path, content):
    from tactile_compliance.data.object_table import ObjectTableError

    write_tree(tmp_path / "src", grasps=1, augmentations=1)
    (tmp_path / "objects.csv").write_bytes(content)
    before = _snapshot(tmp_path)
    with pytest.raises(ObjectTableError, match=r"objects\.csv") as caught:
        _import(tmp_path / "src", tmp_path / "store", object_table=tmp_path / "objects.csv")
    assert isinstance(caught.value, DataImportError)
    assert _snapshot(tmp_path) == before


def _disk_full(*args, **kwargs):
    raise OSError(errno.ENOSPC, "No space left on device")


@pytest.mark.parametrize("where", ["frames", "table", "header"])
def test_full_disk_is_one_clear_error_and_leaves_nothing(tmp_path, monkeypatch, where):
    from tactile_compliance.data.import_report import ImportWriteError

    write_tree(tmp_path / "src", grasps=1, augmentations=2)
    _import(tmp_path / "src", tmp_path / "store", fingers="markerless")
    before = _snapshot(tmp_path)
    if where == "frames":
        monkeypatch.setattr(store_writer, "_write_all", _disk_full)
    elif where == "table":
        monkeypatch.setattr(pd.DataFrame, "to_parquet", _disk_full)
    else:
        monkeypatch.setattr(store_writer, "_write_json", _disk_full)
    for out, overwrite in ((tmp_path / "new" / "store", False), (tmp_path / "store", True)):
        with pytest.raises(ImportWriteError, match="No space left on device") as caught:
            _import(tmp_path / "src", out, overwrite=overwrite)
        assert str(out) in str(caught.value)
        # No partial directory, no half store, no new parent directory; the old store intact.
        assert _snapshot(tmp_path) == before
    # The command line tells a failed write (exit 1) from bad input (exit 2).
    from typer.testing import CliRunner

    from tactile_compliance.cli import app

    args = ["import", "burgess", str(tmp_path / "src"), "--out", str(tmp_path / "other")]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 1, result.output
    assert "No space left on device" in result.output
    assert _snapshot(tmp_path) == before


# -------------------------------------------------------------------------- 4 frame size
def test_frame_size_is_the_majority_not_the_first_file(tmp_path):
    src = tmp_path / "src"
    write_tree(src)
    first = src / "foam_block" / "grasp=0" / "augmentation=0"
    dump(first / "RGB.pkl", np.full((3, 10, 10, 3), 0.5))
    dump(first / "RGB_markers.pkl", np.full((3, 10, 10, 3), 0.5))
    report = _import(src, tmp_path / "store")
    store = GraspStore.open(tmp_path / "store")
    assert store.image_size == (12, 16) and len(store) == 22
    assert report.reasons() == {"wrong array shape": 2}
    assert store.header.creation_parameters["source_image_size"] == [12, 16]


def test_yuan_frame_size_is_the_majority(tmp_path):

    src = tmp_path / "videos"
    src.mkdir()
    write_level_video(src / "AAA_10_1.avi", [20, 60, 100], size=(16, 16))
    for n in range(3):
        write_level_video(src / f"BASIC_60_{n}.avi", [20, 60, 100])
    import_yuan(src, tmp_path / "store", progress=False)
    assert GraspStore.open(tmp_path / "store").image_size == (24, 32)


def _reconstruct_pickle(shape: tuple[int, ...]) -> bytes:
    """A ~100-byte pickle that makes numpy allocate ``shape`` uninitialised bytes."""
    frames = pickle.dumps(np.zeros((0,), np.uint8), protocol=2)
    # Swap the declared (0,) shape of _reconstruct for a big one; the data stays empty.
    return frames.replace(b"K\x00\x85", pickle.dumps(shape, protocol=2)[2:-3], 1)


class _HugeNdarray:
    def __reduce__(self):
        return (np.ndarray, ((3, 4000, 4000, 3), "u1"))


@pytest.mark.parametrize("kind", ["reconstruct", "ndarray", "setstate"])
def test_oversized_arrays_are_refused_before_allocation(tmp_path, kind):
    from tactile_compliance.data.safe_pickle import (
        MAX_ARRAY_ELEMENTS,
        ArrayTooLargeError,
        load_numpy_pickle,
    )

    assert MAX_ARRAY_ELEMENTS == 64 * 2**20
    path = tmp_path / "RGB.pkl"
    if kind == "reconstruct":
        path.write_bytes(_reconstruct_pickle((3, 4000, 4000, 3)))
    elif kind == "ndarray":
        path.write_bytes(pickle.dumps(_HugeNdarray(), protocol=4))
    else:  # the usual layout, with a declared shape far larger than the data
        data = pickle.dumps(np.zeros((3, 4, 4, 3), np.uint8), protocol=2)
        small, huge = (
            pickle.dumps(s, protocol=2)[2:-3] for s in ((3, 4, 4, 3), (3, 4000, 4000, 3))
        )
        assert small in data
        path.write_bytes(data.replace(small, huge, 1))
    assert path.stat().st_size < 600
    tracemalloc.start()
    try:
        with pytest.raises((ArrayTooLargeError, pickle.UnpicklingError, ValueError)) as caught:
            load_numpy_pickle(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 20e6, f"{peak / 1e6:.0f} MB allocated"
    if kind != "setstate":
        assert isinstance(caught.value, ArrayTooLargeError)
        assert "(3, 4000, 4000, 3)" in str(caught.value) and "67108864" in str(caught.value)


def test_declared_bytes_beyond_the_file_are_not_allocated(tmp_path):
    from tactile_compliance.data.safe_pickle import load_numpy_pickle

    path = tmp_path / "forces.pkl"
    path.write_bytes(b"\x80\x04\x8e" + (3 * 10**9).to_bytes(8, "little") + b"\x00" * 16)
    tracemalloc.start()
    try:
        with pytest.raises(pickle.UnpicklingError):
            load_numpy_pickle(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 20e6


@pytest.mark.parametrize("protocol", range(6))
def test_declared_shape_is_read_without_the_data(tmp_path, protocol):
    from tactile_compliance.data.safe_pickle import load_numpy_pickle, peek_array_shape

    path = tmp_path / "RGB.pkl"
    for array in (
        np.random.default_rng(0).random((3, 5, 7, 3)).astype(np.float32),
        np.asfortranarray(np.zeros((3, 5, 7, 3), ">f8")),
        np.arange(3.0),
    ):
        path.write_bytes(pickle.dumps(array, protocol=protocol))
        assert peek_array_shape(path) == array.shape
        loaded = load_numpy_pickle(path)  # (numpy itself may unpickle >f8 as native f8)
        assert loaded.dtype.str[1:] == array.dtype.str[1:] and np.array_equal(loaded, array)
    path.write_bytes(b"not a pickle")
    assert peek_array_shape(path) is None


def test_oversized_pickle_is_one_skipped_sample(tmp_path):
    src = tmp_path / "src"
    write_tree(src)
    bomb = src / "rubber_ball" / "grasp=1" / "augmentation=0" / "RGB.pkl"
    bomb.write_bytes(_reconstruct_pickle((3, 4000, 4000, 3)))
    report = _import(src, tmp_path / "store")
    assert [(Path(p).name, r.split(":")[0]) for p, r in report.problems] == [
        ("RGB.pkl", "array too large")
    ]
    assert len(GraspStore.open(tmp_path / "store")) == 23


def test_nothing_imported_fails(tmp_path):
    from typer.testing import CliRunner

    from tactile_compliance.cli import app
    from tactile_compliance.data.import_report import NothingImportedError

    src = tmp_path / "src"
    write_tree(src, grasps=1, augmentations=1)
    for forces in src.rglob("forces.pkl"):
        dump(forces, np.array(["x", "y", "z"]))
    before = _snapshot(tmp_path)
    with pytest.raises(NothingImportedError, match="wrong dtype") as caught:
        _import(src, tmp_path / "store")
    assert caught.value.report is not None and len(caught.value.report.problems) == 3
    result = CliRunner().invoke(app, ["import", "burgess", str(src), "--out", str(tmp_path / "s")])
    assert result.exit_code == 2, result.output  # bad input: nothing importable
    assert _snapshot(tmp_path) == before


# ------------------------------------------------------------------- 9 kills and leftovers
_KILLED_IMPORT = textwrap.dedent(
    """
    import sys, time
    from tactile_compliance.data import store_writer
    from tactile_compliance.data.burgess import import_burgess

    append = store_writer.GraspStoreWriter.append

    def slow_append(self, *args, **kwargs):
        sample_id = append(self, *args, **kwargs)
        print("appended", flush=True)
        time.sleep(120)
        return sample_id

    store_writer.GraspStoreWriter.append = slow_append
    import_burgess(sys.argv[1], sys.argv[2], progress=False)
    """
)


def test_partial_store_of_a_killed_import_is_removed_by_the_next(tmp_path):
    src, out = tmp_path / "src", tmp_path / "store"
    write_tree(src, grasps=1, augmentations=1)
    child = subprocess.Popen(
        [sys.executable, "-c", _KILLED_IMPORT, str(src), str(out)],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert child.stdout is not None and child.stdout.readline().strip() == "appended"
    finally:
        os.kill(child.pid, signal.SIGKILL)
        child.wait()
    leftovers = [p for p in tmp_path.iterdir() if p.name.startswith(".store.partial-")]
    assert len(leftovers) == 1 and not out.exists()
    # A partial directory of a live import, and one not written by us, are left alone.
    live = GraspStoreWriter(out, (12, 16), "test")
    (tmp_path / ".store.partial-mine").mkdir()
    (tmp_path / ".store.partial-mine" / "keep.txt").write_text("not ours")
    _import(src, out)
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == sorted(["src", "store", live._tmp.name, ".store.partial-mine"])
    assert len(GraspStore.open(out)) == 6
    live.abort()
    assert sorted(p.name for p in tmp_path.iterdir()) == [".store.partial-mine", "src", "store"]


def test_old_store_of_an_import_killed_while_swapping_comes_back(tmp_path):
    src, out = tmp_path / "src", tmp_path / "store"
    write_tree(src, grasps=1, augmentations=1)
    _import(src, out, fingers="markers")
    before = _snapshot(out)
    # Killed between "old store -> backup" and "new store -> out".
    backup = tmp_path / f".store.old-{_dead_pid()}-0a1b2c3d"
    os.rename(out, backup)
    with pytest.raises(DataImportError, match="already exists"):
        _import(src, out)
    assert _snapshot(out) == before and not backup.exists()


@pytest.mark.parametrize("umask", [0o022, 0o027])
def test_created_files_follow_the_umask(tmp_path, umask):
    write_tree(tmp_path / "src", grasps=1, augmentations=1)
    old = os.umask(umask)
    try:
        _import(tmp_path / "src", tmp_path / "deep" / "store")
    finally:
        os.umask(old)
    for path in [tmp_path / "deep", *(tmp_path / "deep").rglob("*")]:
        mode = path.stat().st_mode & 0o777
        expected = (0o777 if path.is_dir() else 0o666) & ~umask
        assert mode == expected, f"{path}: {oct(mode)} != {oct(expected)}"


# ------------------------------------------------------------------------- 10 yuan videos
def test_every_skipped_video_is_reported(tmp_path):

    src = tmp_path / "videos"
    src.mkdir()
    write_level_video(src / "BASIC_60_1.avi", [20, 60, 100])
    writer = cv2.VideoWriter(
        str(src / "BASIC_40_1.mp4"), cv2.VideoWriter_fourcc(*"mp4v"), 30, (32, 24)
    )
    for level in (20, 90, 60):
        writer.write(np.full((24, 32, 3), level, np.uint8))
    writer.release()
    (src / "BASIC_50_1.mp4").write_bytes(b"\x00\x00\x00\x18ftypmp42 truncated")
    (src / "notes.mp4").write_bytes(b"")
    (src / "readme.txt").write_text("not a video")
    report = import_yuan(src, tmp_path / "store", progress=False)
    problems = {Path(p).name: r for p, r in report.problems}
    assert set(problems) == {"BASIC_50_1.mp4", "notes.mp4"}
    assert problems["BASIC_50_1.mp4"].startswith("unreadable video")
    assert problems["notes.mp4"].startswith("unexpected file name")
    assert set(GraspStore.open(tmp_path / "store").samples["object"]) == {"BASIC_60", "BASIC_40"}
