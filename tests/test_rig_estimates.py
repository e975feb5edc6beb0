"""The rig-corrected estimates as data (issue 40): ``record --rig`` and the generator write
them next to the dataset's two with the rig stiffness in the grasp's units, ``import``
carries them into the store's columns, and a store written before them opens with none.
The model side (FWR through train, predict, ONNX and live) is in test_input_strategies."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from tactile_compliance.cli import app
from tactile_compliance.data.raw_layout import ESTIMATE_FILES, RIG_ESTIMATE_FILES, load_estimate
from tactile_compliance.data.store import (
    RIG_ESTIMATE_COLUMNS,
    SAMPLES_FILE,
    GraspStore,
)
from tactile_compliance.physics.estimators import DATASET_UNITS, GraspUnits
from tactile_compliance.synthetic.rig import DATASET_RIG, WEDGE_2023_RIG
from toy_store import make_toy_store

runner = CliRunner()


def cli(*args: object) -> str:
    result = runner.invoke(app, [str(a) for a in args])
    assert result.exit_code == 0, result.output
    return result.output


def test_units_round_trip_the_rig_stiffness_and_name_it() -> None:
    units = GraspUnits(rig_stiffness_n_per_m=3440.7)
    assert GraspUnits.from_dict(json.loads(json.dumps(units.to_dict()))) == units
    assert "rig-corrected for a 3441 N/m rig" in units.describe()
    # Without a rig the file keeps the keys it always had.
    assert set(DATASET_UNITS.to_dict()) == {"analytical_estimator", "depth_model", "px_per_mm"}
    assert units != DATASET_UNITS
    for bad in (0.0, -1.0, math.inf, math.nan):
        with pytest.raises(ValueError, match="rig_stiffness_n_per_m"):
            GraspUnits(rig_stiffness_n_per_m=bad)


def test_record_with_a_rig_writes_them_and_import_carries_them_into_the_store(tmp_path) -> None:
    from helpers import make_replay_grasp

    grasp = make_replay_grasp(tmp_path / "grasp", (250, 350))
    source = [f"video:{grasp['video']}", "--readings", grasp["readings"]]
    data = tmp_path / "data"
    common = ["--out", data, "--modulus", grasp["modulus_pa"], "--json"]
    recorded = json.loads(cli("record", *source, "--rig", "dataset", "--object", "ball", *common))
    rig = recorded["rig_corrected_pa"]
    assert all(v is not None and v > 0 for v in rig)
    units = json.loads((data / "ball" / "grasp=0" / "units.json").read_text())
    assert units["rig_stiffness_n_per_m"] == pytest.approx(DATASET_RIG.stiffness_n_per_m)
    samples = sorted((data / "ball" / "grasp=0").glob("augmentation=*"))
    assert samples
    for sample in samples:
        written = [load_estimate(sample, name) for name in RIG_ESTIMATE_FILES]
        assert written == pytest.approx(rig, rel=1e-12)
        plain = [load_estimate(sample, name) for name in ESTIMATE_FILES]
        assert written != pytest.approx(plain)

    cli("import", "burgess", data, "--out", tmp_path / "store", "--fingers", "markerless")
    store = GraspStore.open(tmp_path / "store")
    np.testing.assert_allclose(
        store.samples[list(RIG_ESTIMATE_COLUMNS)].to_numpy(), np.tile(rig, (len(store), 1))
    )
    assert store.units.rig_stiffness_n_per_m == pytest.approx(DATASET_RIG.stiffness_n_per_m)

    # A grasp of another rig goes in (the dataset's two estimates still mix), but the
    # dataset's rig-corrected pairs are then not comparable: import leaves them out and
    # says so, and the store names no rig.
    cli("record", *source, "--rig", "wedge-2023", "--object", "cube", *common)
    result = runner.invoke(
        app,
        [
            "import",
            "burgess",
            str(data),
            "--out",
            str(tmp_path / "mixed"),
            "--fingers",
            "markerless",
        ],
    )
    assert result.exit_code == 0, result.output
    assert "no rig-corrected estimates imported: the grasps name different rigs" in result.output
    mixed = GraspStore.open(tmp_path / "mixed")
    assert mixed.units.rig_stiffness_n_per_m is None
    assert mixed.samples[list(RIG_ESTIMATE_COLUMNS)].isna().all().all()
    assert set(mixed.samples["object"]) == {"ball", "cube"}


def test_the_generator_writes_them_at_its_rigs_stiffness(tmp_path) -> None:
    cli(
        "simulate", "--out", tmp_path / "syn", "--objects", 3, "--grasps-per-object", 1,
        "--seed", 0, "--size", "48x64", "--rig", "wedge-2023", "--workers", 1,
    )  # fmt: skip
    grasps = sorted((tmp_path / "syn").glob("*/grasp=*"))
    assert grasps
    checked = 0
    for grasp in grasps:
        units = GraspUnits.from_dict(json.loads((grasp / "units.json").read_text()))
        assert units.rig_stiffness_n_per_m == pytest.approx(WEDGE_2023_RIG.stiffness_n_per_m)
        for sample in grasp.glob("augmentation=*"):
            plain = [load_estimate(sample, name) for name in ESTIMATE_FILES]
            rig = [load_estimate(sample, name) for name in RIG_ESTIMATE_FILES]
            for p, r in zip(plain, rig, strict=True):
                if math.isfinite(p) and math.isfinite(r):
                    # Taking the rig's closure out leaves less to the object: stiffer.
                    assert r > p
                    checked += 1
    assert checked > 0


def test_a_store_written_before_them_opens_with_none(tmp_path) -> None:
    store = make_toy_store(tmp_path / "store", n_objects=3, grasps=1)
    table = pd.read_parquet(store.path / SAMPLES_FILE)
    old = table.drop(columns=[*RIG_ESTIMATE_COLUMNS, "rig_stiffness_n_per_m"])
    old.to_parquet(store.path / SAMPLES_FILE, index=False)
    reopened = GraspStore.open(store.path)
    assert list(reopened.samples.columns) == list(table.columns)
    assert reopened.samples[list(RIG_ESTIMATE_COLUMNS)].isna().all().all()
    assert reopened.units == DATASET_UNITS
    pd.testing.assert_frame_equal(
        reopened.samples.drop(columns=[*RIG_ESTIMATE_COLUMNS, "rig_stiffness_n_per_m"]), old
    )
