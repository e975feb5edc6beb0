"""Units travel with each grasp (issue 43): the analytical estimator, depth model and
pixel density of a grasp's estimates are in its own ``grasp=g/units.json`` and in every
store row of it, so copying objects between datasets or deleting a file relabels nothing;
a tree without them (the public dataset) is imported by the dataset heuristic, and the
report says so; ``evaluate`` refuses what ``predict`` and ``live`` refuse.

The grasps are built in memory (a force ramp and small random frames, milliseconds each).
"""

from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from tactile_compliance.acquisition.calibration import SensorCalibration
from tactile_compliance.acquisition.capture import CapturedGrasp
from tactile_compliance.acquisition.recording import ObjectInfo, write_grasp
from tactile_compliance.acquisition.sensors import FrameGeometry
from tactile_compliance.cli import app
from tactile_compliance.data.burgess import import_burgess
from tactile_compliance.data.import_report import ImportUnitsError
from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.data.store import GraspStore, StoreError
from tactile_compliance.data.store_writer import GraspStoreWriter
from tactile_compliance.models import create_model
from tactile_compliance.physics.estimators import SensorUnits
from tactile_compliance.runs.checkpoint import save_checkpoint
from tactile_compliance.runs.run_inputs import RunInputs
from toy_store import make_toy_store

runner = CliRunner()


def captured(n: int = 40, seed: int = 0) -> CapturedGrasp:
    """A press to 60 N over ``n`` frames of 24 x 32 px at 30 fps."""
    t = np.arange(n, dtype=np.float64)
    force = 60.0 * np.clip((t - 6) / 20, 0, 1) ** 1.5
    frames = np.random.default_rng(seed).integers(100, 140, (n, 24, 32, 3), dtype=np.uint8)
    return CapturedGrasp(t / 30.0, frames, force, np.full(n, 0.05))


def calibration(px_per_mm: float) -> SensorCalibration:
    """A sensor calibrated for its pixel density (11 px/mm, not the Wedge's 16.4)."""
    return SensorCalibration(FrameGeometry(), captured().frames[0], px_per_mm=px_per_mm)


def record(out: Path, name: str, px_per_mm: float | None = None) -> None:
    sensor = None if px_per_mm is None else calibration(px_per_mm)
    write_grasp(captured(), out, ObjectInfo(name, 1e5), sensor=sensor)


def _import(src: Path, out: Path) -> object:
    return import_burgess(src, out, fingers="markerless", progress=False)


def test_record_writes_the_units_into_each_grasp_and_a_deleted_record_relabels_nothing(
    tmp_path,
):
    data = tmp_path / "data"
    record(data, "ball", px_per_mm=11.0)
    assert json.loads((data / "ball" / "grasp=0" / "units.json").read_text()) == {
        "analytical_estimator": "dataset",
        "depth_model": "dataset",
        "px_per_mm": 11.0,
    }
    # There is no dataset-wide record to delete any more (recording.json was one), and
    # recording without the calibration is still refused: the earlier grasp says 11 px/mm.
    (data / "recording.json").unlink(missing_ok=True)
    with pytest.raises(ValueError, match=r"11 px/mm .*this recording has .*Wedge's pixel"):
        record(data, "cube")
    assert not (data / "cube").exists()
    store = GraspStore.open(_import(data, tmp_path / "store").store_dir)
    assert store.samples["px_per_mm"].tolist() == [11.0] * len(store)
    assert store.sensor_units == SensorUnits("dataset", 11.0)


@pytest.mark.parametrize("unnamed", [False, True], ids=["other calibration", "no units.json"])
def test_an_object_copied_in_from_other_units_is_refused_at_import_in_one_line(tmp_path, unnamed):
    """An object recorded at 11 px/mm copied into a dataset recorded at the Wedge's
    density; or a grasp without units.json (the public dataset's) copied into a
    calibrated dataset: both name the two grasps and their units, and nothing is written."""
    here, there = tmp_path / "here", tmp_path / "there"
    record(here, "cube", px_per_mm=None if unnamed else 16.0)
    record(there, "ball", px_per_mm=11.0)
    shutil.copytree(there / "ball", here / "ball")
    if unnamed:
        (here / "cube" / "grasp=0" / "units.json").unlink()
    with pytest.raises(ImportUnitsError) as raised:
        _import(here, tmp_path / "store")
    message = str(raised.value)
    assert "\n" not in message and "grasps in two units" in message
    assert (
        "ball/grasp=0 has the dataset estimator on the dataset's depth heuristic at 11" in message
    )
    other = "the Wedge's pixel density" if unnamed else "16 px/mm"
    assert f"cube/grasp=0 has the dataset estimator on the dataset's depth heuristic at {other}"
    assert ("(no units.json: the dataset's heuristic)" in message) == unnamed
    assert not (tmp_path / "store").exists()
    result = runner.invoke(app, ["import", "burgess", str(here), "--out", str(tmp_path / "s")])
    assert result.exit_code != 0 and "grasps in two units" in result.output
    errors = [line for line in result.output.splitlines() if "Reading frame sizes" not in line]
    assert len(errors) == 1 and errors[0].startswith("error: "), result.output


def test_an_import_without_units_takes_the_dataset_heuristic_and_says_so(tmp_path):
    data = tmp_path / "data"
    record(data, "ball")
    record(data, "cube")
    for path in data.glob("*/grasp=*/units.json"):  # as in the public dataset
        path.unlink()
    report = _import(data, tmp_path / "store")
    assert report.grasps_without_units == 2
    assert (
        "Units: 2 grasp(s) name no units (no units.json, as in the public dataset): their "
        "estimates are taken, by the dataset's heuristic, to be from the dataset estimator "
        "on the dataset's depth heuristic at the Wedge's pixel density."
    ) in report.format().splitlines()
    assert report.to_dict()["grasps_without_units"] == 2
    samples = GraspStore.open(tmp_path / "store").samples
    assert set(samples["depth_model"]) == {"dataset"} and samples["px_per_mm"].isna().all()
    # With units.json in every grasp, the report names where they came from.
    record(data, "ball")
    (data / "ball" / "grasp=0").rename(data / "ball" / "old")
    shutil.rmtree(data / "cube")
    shutil.rmtree(data / "ball" / "old")
    again = _import(data, tmp_path / "again")
    assert again.grasps_without_units == 0
    assert "(each grasp's units.json)" in again.format()


def test_a_store_whose_rows_disagree_is_refused_where_its_units_are_read(tmp_path):
    rows = [{"object": "a", "modulus_pa": 1e5}, {"object": "b", "modulus_pa": 1e6}]
    rows[1]["px_per_mm"] = 11.0
    with GraspStoreWriter(tmp_path / "s", (4, 5), "test") as writer:
        for row in rows:
            writer.append(np.full((3, 4, 5, 3), 0.5), row)
        with pytest.raises(ValueError, match="unknown depth model 'banana'"):
            writer.append(np.full((3, 4, 5, 3), 0.5), {**rows[0], "depth_model": "banana"})
    store = GraspStore.open(tmp_path / "s")
    assert store.samples["analytical_estimator"].tolist() == ["dataset", "dataset"]
    assert math.isnan(store.samples["px_per_mm"][0])
    with pytest.raises(StoreError, match=r"rows in two units: sample 0 \(a\) .*sample 1 \(b\)"):
        store.sensor_units  # noqa: B018 (a property that raises)
    with pytest.raises(StoreError, match="rows in two units"):
        store.analytical_estimator  # noqa: B018


def _all_checkpoint(path: Path, units: SensorUnits) -> Path:
    model = create_model("top10nn", inputs="ALL")
    run_inputs = RunInputs((72, 72), (32, 32), NormalisationConstants(), "ALL", sensor=units)
    return save_checkpoint(path, model, run_inputs=run_inputs, config={}, seed=0)


def test_evaluate_refuses_a_checkpoint_in_other_units_as_predict_does(tmp_path):
    calibrated = make_toy_store(
        tmp_path / "calibrated", n_objects=4, grasps=1, units={"px_per_mm": 11.0}
    )
    run = tmp_path / "run"
    run.mkdir()
    _all_checkpoint(run / "best.pt", SensorUnits())  # trained on the Wedge's estimates
    lines = {}
    for command in (
        ["evaluate", run, "--store", calibrated.path],
        ["predict", run, calibrated.path],
    ):
        result = runner.invoke(app, [str(a) for a in command])
        assert result.exit_code == 2, result.output
        assert len(result.output.strip().splitlines()) == 1, result.output
        lines[command[0]] = result.output
    for line in lines.values():
        assert "other units" in line and "11 px/mm" in line and "the Wedge's pixel" in line
    # The same store with a checkpoint in its units is evaluated.
    _all_checkpoint(run / "best.pt", SensorUnits("dataset", 11.0))
    result = runner.invoke(app, ["evaluate", str(run), "--store", str(calibrated.path)])
    assert result.exit_code == 0, result.output
