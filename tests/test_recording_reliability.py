"""``record`` never loses a grasp or a label (issue 30): its output is claimed, concurrent
recordings keep every row, the table follows ``metadata.json``, a full disk leaves no
label behind, and implausible names and readings are refused before anything is written.

The grasps are built in memory (``CapturedGrasp``: a force ramp and small random
frames), so each write takes milliseconds and four writers can race in real processes.
"""

from __future__ import annotations

import errno
import json
import multiprocessing
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from tactile_compliance.acquisition.capture import CapturedGrasp
from tactile_compliance.acquisition.recording import (
    OBJECT_TABLE_FILE,
    ObjectInfo,
    write_grasp,
)
from tactile_compliance.data import raw_layout
from tactile_compliance.outputs import OutputExistsError, claim_output_dir
from toy_store import make_toy_store


def captured(width_m: float = 0.05, n: int = 40, seed: int = 0) -> CapturedGrasp:
    """A press to 60 N over ``n`` frames of 24 x 32 px at 30 fps."""
    t = np.arange(n, dtype=np.float64)
    force = 60.0 * np.clip((t - 6) / 20, 0, 1) ** 1.5
    rng = np.random.default_rng(seed)
    frames = rng.integers(100, 140, (n, 24, 32, 3), dtype=np.uint8)
    return CapturedGrasp(t / 30.0, frames, force, np.full(n, width_m))


def table(out: Path) -> pd.DataFrame:
    return pd.read_csv(out / OBJECT_TABLE_FILE, dtype=str, keep_default_na=False)


# ---------------------------------------------------------------------- the output
def test_record_refuses_a_store_a_run_directory_and_foreign_files(tmp_path):
    store = make_toy_store(tmp_path / "store", n_objects=2, grasps=1).path
    run = claim_output_dir(tmp_path / "run", "run")
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    for out in (store, run, foreign):
        before = sorted(p.relative_to(out) for p in out.rglob("*"))
        with pytest.raises(OutputExistsError):
            write_grasp(captured(), out, ObjectInfo("ball", 1e5))
        assert sorted(p.relative_to(out) for p in out.rglob("*")) == before
    # A dataset that record wrote is reused; without its marker it is no one's.
    out = tmp_path / "data"
    write_grasp(captured(), out, ObjectInfo("ball", 1e5))
    assert write_grasp(captured(), out, ObjectInfo("ball", 1e5)).grasp == 1
    (out / ".tactile-compliance.json").unlink()
    with pytest.raises(OutputExistsError):
        write_grasp(captured(), out, ObjectInfo("ball", 1e5))


# ---------------------------------------------------------------------- concurrency
def _writer(out: str, name: str, barrier) -> None:  # barrier: a multiprocessing.Barrier
    barrier.wait()
    try:
        write_grasp(captured(seed=len(name)), out, ObjectInfo(name, 1e5))
    except BaseException:
        import traceback

        Path(out).with_name(f"{Path(out).name}-{name}.error").write_text(traceback.format_exc())
        raise


def test_four_concurrent_records_keep_every_row(tmp_path):
    """Four processes record four objects at once: into a new dataset (they race to
    create it) and again into the same one; every row and every grasp survives."""
    names = ["a", "bb", "ccc", "dddd"]
    context = multiprocessing.get_context("fork")
    for out, trial in [(tmp_path / "data", 0), (tmp_path / "data", 1), (tmp_path / "new", 0)]:
        barrier = context.Barrier(len(names))
        workers = [
            context.Process(target=_writer, args=(str(out), name, barrier)) for name in names
        ]
        for worker in workers:
            worker.start()
        for worker in workers:
            worker.join(120)
        errors = [p.read_text() for p in tmp_path.glob("*.error")]
        assert [w.exitcode for w in workers] == [0] * len(names), errors
        rows = table(out).set_index("Label")
        assert sorted(rows.index) == sorted(names)
        assert all(rows.loc[n, "Trials Recorded?"] == str(trial + 1) for n in names)
        assert all(len(list((out / n).glob("grasp=*"))) == trial + 1 for n in names)
        assert not list(out.glob("*.tmp")) and not list(out.glob("*/.partial*"))


# ---------------------------------------------------------------------- labels
def test_the_table_follows_metadata_after_an_object_is_recorded_again(tmp_path):
    import shutil

    out = tmp_path / "data"
    write_grasp(captured(), out, ObjectInfo("ball", 1e5, "Rubber"))
    write_grasp(captured(), out, ObjectInfo("cube", 2e6))
    shutil.rmtree(out / "ball")  # the user deletes the recordings and records again
    write_grasp(captured(), out, ObjectInfo("ball", 3e7, "Foam"))
    meta = json.loads((out / "ball" / "metadata.json").read_text())
    rows = table(out).set_index("Label")
    assert float(rows.loc["ball", "Modulus [Pa]"]) == meta["youngs_modulus"] == 3e7
    assert rows.loc["ball", "Material"] == "Foam" and rows.loc["ball", "Trials Recorded?"] == "1"
    assert float(rows.loc["cube", "Modulus [Pa]"]) == 2e6


@pytest.mark.parametrize("name", ["ball\n", "ba\nll", "ball\t", "ball\r", "bäll", "", "-x"])
def test_object_names_with_control_characters_are_refused(name):
    with pytest.raises(ValueError, match="object name"):
        ObjectInfo(name, 1e5)


def test_control_characters_in_material_are_refused():
    with pytest.raises(ValueError, match="control character"):
        ObjectInfo("ball", 1e5, material="Rub\nber")


def test_widths_in_millimetres_are_refused_before_anything_is_written(tmp_path):
    out = tmp_path / "data"
    with pytest.raises(ValueError, match=r"width 17\.4 m is outside the plausible range"):
        write_grasp(captured(width_m=17.4), out, ObjectInfo("ball", 1e5))
    assert not out.exists()


# ---------------------------------------------------------------------- a full disk
def test_a_full_disk_leaves_no_metadata_and_no_partial_grasp(tmp_path, monkeypatch):
    out = tmp_path / "data"
    write_grasp(captured(), out, ObjectInfo("cube", 2e6))
    before = sorted(p.relative_to(out) for p in out.rglob("*") if p.name != ".record.lock")

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(raw_layout, "dump_numpy_pickle", full)
    with pytest.raises(OSError, match="No space left"):
        write_grasp(captured(), out, ObjectInfo("ball", 1e5))
    after = sorted(p.relative_to(out) for p in out.rglob("*") if p.name != ".record.lock")
    assert after == before  # no ball/, no ball/metadata.json, no .partial-grasp
