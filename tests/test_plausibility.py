"""One set of plausibility rules: the importer, the store and the estimator agree.

A physically impossible value (a negative force, a width in metres that is really
millimetres, an infinite estimate, float frames outside [0, 1], a date where a number
belongs) must be skipped and reported by the importer, refused by the store and rejected
by the estimator, each naming the value's unit.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
import torch

from burgess_tree import dump, write_tree
from tactile_compliance.data import plausibility, raw_layout, store
from tactile_compliance.data.burgess import import_burgess
from tactile_compliance.data.inputs import INPUTS
from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.data.plausibility import RULES, PlausibleRange
from tactile_compliance.data.store import GraspStore, StoreError
from tactile_compliance.data.store_writer import GraspStoreWriter
from tactile_compliance.inference import ComplianceEstimator, input_checks
from tactile_compliance.models import create_model
from tactile_compliance.runs.run_inputs import RunInputs

BAD_SAMPLE = ("foam_block", 0, 1)  # (object, grasp, augmentation) that gets the bad value


# ---------------------------------------------------------------------- the rules table
def test_every_rule_has_a_unit_a_range_and_a_reason():
    assert set(RULES) == {"force", "width", "estimate", "modulus", "frame value", "depth"}
    for name, rule in RULES.items():
        assert rule.quantity == name
        assert rule.unit.strip(), name
        assert rule.low < rule.high, name
        assert rule.reason.strip(), name
        assert isinstance(rule.low_inclusive, bool) and isinstance(rule.high_inclusive, bool)
        assert rule.unit in rule.interval()
    with pytest.raises(ValueError, match="low"):
        PlausibleRange("x", "N", 1.0, 1.0, reason="why")
    with pytest.raises(ValueError, match="unit"):
        PlausibleRange("x", "", 0.0, 1.0, reason="why")


def test_the_consumers_read_the_same_rules():
    # Estimator: its ranges are the rules themselves, not literals of its own.
    assert INPUTS["force"].rule is plausibility.FORCE
    assert INPUTS["width"].rule is plausibility.WIDTH
    assert INPUTS["estimates"].rule is plausibility.ESTIMATE
    assert INPUTS["depth"].rule is plausibility.DEPTH
    assert INPUTS["frames"].rule is plausibility.FRAME
    assert plausibility.FRAME.tolerance == input_checks._RANGE_TOLERANCE
    # Store columns and importer files.
    assert store.COLUMN_RULES["modulus_pa"] is plausibility.MODULUS
    for column in (*store.FORCE_COLUMNS, *store.WIDTH_COLUMNS, *store.ESTIMATE_COLUMNS):
        assert store.COLUMN_RULES[column] in RULES.values()
    assert raw_layout.FILE_RULES["forces.pkl"] is plausibility.FORCE
    assert raw_layout.FILE_RULES["RGB.pkl"] is plausibility.FRAME


def test_bounds_and_nan():
    force, estimate, frame = plausibility.FORCE, plausibility.ESTIMATE, plausibility.FRAME
    assert force.outside([-1e-9, 0.0, 60.0, 1000.0, 1000.1, np.nan]).tolist() == [
        True,
        False,
        False,
        False,
        True,
        False,  # NaN is missing, not implausible
    ]
    assert estimate.outside([0.0, 1e-3, 1e20, np.inf, -np.inf]).tolist() == [
        True,
        False,
        False,
        True,
        True,
    ]
    assert not estimate.contains(np.nan)
    # Decoded store frames reach (255 + 0.5) / 255: within one grey level.
    assert frame.violation(np.array([(255 + 0.5) / 255, -0.5 / 255])) is None
    # Real difference images have a few saturated pixels outside [0, 1] (the generator's
    # full-size extremes: -0.21 and 1.13 in at most 0.12 % of a sample's values).
    image = np.full(1000, 0.5)
    image[:10] = [-0.21, 1.13, -0.5, 1.5, *[1.1] * 6]
    assert frame.violation(image) is None
    image[10] = 1.1  # 11 of 1000: more than 1 % is no difference image
    assert "11 of 1000 values" in str(frame.violation(image))
    image[5:11] = 0.5
    image[0] = -0.51  # beyond what (frame - reference) / 255 + 0.5 can reach
    assert "frame value -0.51" in str(frame.violation(image))
    assert frame.violation(np.full(4, 200.0)) is not None  # 0..255 as floats
    assert plausibility.format_number(1e13) == "1e13" and plausibility.format_number(-50) == "-50"


# ---------------------------------------------------------------------- one bad value, three places
@dataclass(frozen=True)
class Case:
    """One implausible value as each consumer meets it."""

    file: str  # the file of an augmentation directory that holds it
    content: Callable[[dict[str, np.ndarray]], np.ndarray]  # from the good arrays
    argument: str  # the estimator's argument
    given: Any  # what the estimator receives
    column: str | None  # the store column; None: frames (not in the table)
    stored: Any  # the value in that column
    unit: str  # the unit every message must name
    reason: str  # how the import report's reason starts


def _forces(values: dict[str, np.ndarray], index: int, value: float) -> np.ndarray:
    forces = values["forces.pkl"].copy()
    forces[index] = value
    return forces


def _widths(values: dict[str, np.ndarray], index: int, value: float) -> np.ndarray:
    widths = values["widths.pkl"].copy()
    widths[index] = value
    return widths


def _rgb(values: dict[str, np.ndarray], value: float) -> np.ndarray:
    frames = values["RGB.pkl"].copy()
    frames[1] = value  # the middle frame is no difference image
    return frames


def _float_frames(value: float) -> np.ndarray:
    frames = np.random.default_rng(1).uniform(0.4, 0.6, (3, 40, 48, 3)).astype(np.float32)
    frames[1] = value
    return frames


_DATES = np.array(["2024-01-01", "2024-01-02", "2024-01-03"], dtype="datetime64[D]")

CASES = {
    "force -50 N": Case(
        "forces.pkl",
        lambda v: _forces(v, 0, -50.0),
        "force",
        [-50.0, 30.0, 55.0],
        "force_n_0",
        -50.0,
        "N",
        "implausible value",
    ),
    "force 1e9 N": Case(
        "forces.pkl",
        lambda v: _forces(v, 2, 1e9),
        "force",
        [8.0, 30.0, 1e9],
        "force_n_2",
        1e9,
        "N",
        "implausible value",
    ),
    "width -1 m": Case(
        "widths.pkl",
        lambda v: _widths(v, 0, -1.0),
        "width",
        [-1.0, 0.048, 0.046],
        "width_m_0",
        -1.0,
        "m",
        "implausible value",
    ),
    "width 5 m": Case(
        "widths.pkl",
        lambda v: _widths(v, 2, 5.0),
        "width",
        [0.05, 0.048, 5.0],
        "width_m_2",
        5.0,
        "m",
        "implausible value",
    ),
    "estimate inf": Case(
        "elastic_estimate.pkl",
        lambda v: np.array(np.inf),
        "estimates",
        [np.inf, 4e5],
        "elastic_estimate_pa",
        np.inf,
        "Pa",
        "implausible value",
    ),
    "estimate -1e5 Pa": Case(
        "hertz_estimate.pkl",
        lambda v: np.array(-1e5),
        "estimates",
        [2e5, -1e5],
        "hertz_estimate_pa",
        -1e5,
        "Pa",
        "implausible value",
    ),
    "frames 1.5": Case(
        "RGB.pkl",
        lambda v: _rgb(v, 1.5),
        "frames",
        _float_frames(1.5),
        None,
        _float_frames(1.5)[:, :4, :5],
        "full scale",
        "implausible value",
    ),
    "frames -0.3": Case(
        "RGB.pkl",
        lambda v: _rgb(v, -0.3),
        "frames",
        _float_frames(-0.3),
        None,
        _float_frames(-0.3)[:, :4, :5],
        "full scale",
        "implausible value",
    ),
    "datetime64 forces": Case(
        "forces.pkl",
        lambda v: _DATES,
        "force",
        _DATES,
        "force_n_1",
        np.datetime64("2024-01-02"),
        "N",
        "wrong dtype",
    ),
    "complex estimate": Case(
        "elastic_estimate.pkl",
        lambda v: np.array(2e5 + 1e3j),
        "estimates",
        np.array([2e5 + 1e3j, 4e5]),
        "elastic_estimate_pa",
        2e5 + 1e3j,
        "Pa",
        "wrong dtype",
    ),
}


@pytest.mark.parametrize("name", list(CASES))
def test_import_skips_exactly_that_sample_and_reports_it(tmp_path, name):
    case = CASES[name]
    written = write_tree(tmp_path / "src", grasps=1, augmentations=2)
    obj, grasp, augmentation = BAD_SAMPLE
    aug_dir = tmp_path / "src" / obj / f"grasp={grasp}" / f"augmentation={augmentation}"
    dump(aug_dir / case.file, case.content(written[BAD_SAMPLE]))

    report = import_burgess(
        tmp_path / "src", tmp_path / "store", fingers="markerless", progress=False
    )
    assert len(report.problems) == 1, report.problems
    path, reason = report.problems[0]
    assert Path(path) in (aug_dir, aug_dir / case.file)
    assert reason.startswith(f"{case.reason}: {case.file}"), reason
    if case.reason == "implausible value":  # the value, its unit and the allowed range
        rule = raw_layout.FILE_RULES[case.file]
        assert f" {case.unit} is outside the plausible range {rule.interval()}" in reason
    else:  # the dtype, and what was expected instead
        assert f"in {case.unit})" in reason and "expected numbers" in reason
    samples = GraspStore.open(tmp_path / "store").samples
    imported = set(zip(samples["object"], samples["grasp"], samples["augmentation"], strict=True))
    assert len(samples) == len(written) - 1 and BAD_SAMPLE not in imported


@pytest.fixture(scope="module")
def estimator():
    torch.manual_seed(0)
    model = create_model("top10nn", inputs="ALL")
    return ComplianceEstimator(
        model, RunInputs((72, 72), (72, 72), NormalisationConstants(), model.inputs)
    )


GOOD = {
    "frames": np.random.default_rng(0).integers(100, 156, (3, 40, 48, 3), dtype=np.uint8),
    "force": [8.0, 30.0, 58.0],
    "width": [0.050, 0.048, 0.046],
    "estimates": [2e5, 4e5],
}


@pytest.mark.parametrize("name", list(CASES))
def test_estimator_rejects_the_same_value(estimator, name):
    case = CASES[name]
    with pytest.raises(ValueError) as caught:
        estimator.predict(**{**GOOD, case.argument: case.given})
    message = str(caught.value)
    assert case.argument in message and case.unit in message, message


def _good_row(i: int) -> dict[str, Any]:
    return {
        "object": f"obj_{i % 2}",
        "grasp": i,
        "finger": "markerless",
        "material": "Rubber",
        "shape": "Sphere",
        "modulus_pa": 1e5 * (i + 1),
        **dict(zip(store.FORCE_COLUMNS, (5.0, 20.0, 50.0), strict=True)),
        **dict(zip(store.WIDTH_COLUMNS, (0.05, 0.049, 0.048), strict=True)),
        "elastic_estimate_pa": 3e5,
        "hertz_estimate_pa": 1e5,
    }


def _write_good_store(path: Path, n: int = 4) -> None:
    with GraspStoreWriter(path, (4, 5), "test") as writer:
        for i in range(n):
            writer.append(np.full((3, 4, 5, 3), 0.5), _good_row(i))


@pytest.mark.parametrize("name", list(CASES))
def test_store_refuses_the_same_value(tmp_path, monkeypatch, name):
    case = CASES[name]
    path = tmp_path / "s"
    if case.column is None:  # frames are not in the table: the writer refuses them
        with GraspStoreWriter(path, (4, 5), "test") as writer:
            with pytest.raises(ValueError, match=rf"frames: .* {case.unit}"):
                writer.append(case.stored, _good_row(0))
            writer.append(np.full((3, 4, 5, 3), 0.5), _good_row(0))
        assert len(GraspStore.open(path)) == 1
        return
    # The writer refuses the row (so an import can skip it) ...
    with GraspStoreWriter(path, (4, 5), "test") as writer:
        with pytest.raises(ValueError, match=case.column):
            writer.append(np.full((3, 4, 5, 3), 0.5), {**_good_row(0), case.column: case.stored})
        writer.append(np.full((3, 4, 5, 3), 0.5), _good_row(0))
    # ... and opening a table that holds it (written by another tool) fails.
    path = tmp_path / "edited"
    _write_good_store(path)
    table = pd.read_parquet(path / store.SAMPLES_FILE)
    if isinstance(case.stored, np.datetime64):
        table[case.column] = pd.to_datetime(["2024-01-02"] * len(table))
    else:
        table[case.column] = table[case.column].astype(type(case.stored))
        table.loc[1, case.column] = case.stored
    if isinstance(case.stored, complex):  # parquet cannot hold complex numbers: read as is
        monkeypatch.setattr(pd, "read_parquet", lambda *args, **kwargs: table.copy())
    else:
        table.to_parquet(path / store.SAMPLES_FILE, index=False)
    with pytest.raises(StoreError, match=rf"column {case.column} .*{case.unit}"):
        GraspStore.open(path)
    assert any(case.column in problem for problem in store.store_problems(path))


# ---------------------------------------------------------------------- what stays allowed
def test_real_extremes_pass_everywhere(tmp_path, estimator):
    """The public dataset's extremes (~60 N, 0.08 m, estimates 1e2-1e14 Pa, decoded frames
    up to 1.002) and missing values pass all three consumers."""
    written = write_tree(tmp_path / "src", grasps=1, augmentations=1)
    aug_dir = tmp_path / "src" / "foam_block" / "grasp=0" / "augmentation=0"
    dump(aug_dir / "forces.pkl", np.array([0.0, 30.0, 60.0]))
    dump(aug_dir / "widths.pkl", np.array([0.08, 0.079, 0.0]))
    dump(aug_dir / "elastic_estimate.pkl", np.array(1e2))
    dump(aug_dir / "hertz_estimate.pkl", np.array(np.nan))  # a failed fit: missing
    frames = written[("foam_block", 0, 0)]["RGB.pkl"].copy()
    frames[0, 0, 0] = (255 + 0.5) / 255
    frames[1, 2, 3] = 1.13  # saturated pixels of a real difference image
    frames[2, 4, 5] = -0.21
    dump(aug_dir / "RGB.pkl", frames)
    report = import_burgess(tmp_path / "src", tmp_path / "store", progress=False)
    assert report.problems == [] and report.samples_imported == 6
    samples = GraspStore.open(tmp_path / "store").samples
    assert samples["hertz_estimate_pa"].isna().sum() == 2

    result = estimator.predict(
        frames.astype(np.float32),
        force=[0.0, 30.0, 60.0],
        width=[0.08, 0.079, 0.0],
        estimates=[1e2, 1e14],
    )
    assert math.isfinite(result.modulus_pa)
    # Shore videos: no force, width or estimate at all (NaN) is a valid store row.
    with GraspStoreWriter(tmp_path / "shore", (4, 5), "yuan") as writer:
        writer.append(np.full((3, 4, 5, 3), 128, np.uint8), {"object": "a", "modulus_pa": 4e3})
    assert store.store_problems(tmp_path / "shore") == []


def test_labels_outside_the_modulus_range_are_refused(tmp_path):
    objects = {"rigid": (1e14, "Metal", "Cylinder"), "soft": (2e4, "Foam", "Sphere")}
    write_tree(tmp_path / "src", objects=objects, grasps=1, augmentations=1)
    report = import_burgess(tmp_path / "src", tmp_path / "store", progress=False)
    assert [Path(p).name for p, _ in report.problems] == ["rigid"]
    assert "invalid modulus: 100000000000000.0: modulus 1e14 Pa" in report.problems[0][1]
    assert "(0, 1e13] Pa" in report.problems[0][1]
    with GraspStoreWriter(tmp_path / "s", (4, 5), "test") as writer:
        with pytest.raises(ValueError, match=r"modulus_pa must be .*<= 1e13 Pa"):
            writer.append(np.zeros((3, 4, 5, 3)), {**_good_row(0), "modulus_pa": 1e14})
        writer.append(np.zeros((3, 4, 5, 3)), _good_row(0))
    table = pd.read_parquet(tmp_path / "s" / store.SAMPLES_FILE)
    table.loc[0, "modulus_pa"] = 1e14
    table.to_parquet(tmp_path / "s" / store.SAMPLES_FILE, index=False)
    with pytest.raises(StoreError, match=r"column modulus_pa must be .*<= 1e13 Pa.*row 0"):
        GraspStore.open(tmp_path / "s")


def test_non_numeric_values_are_refused_not_cast(tmp_path, estimator):
    # bool and numeric text are no numbers either; a Python list of floats is.
    for bad in ([True, True, False], ["8", "30", "58"], [8.0, "30", 58.0]):
        with pytest.raises(ValueError, match=r"`force` .* must be numeric"):
            estimator.predict(**{**GOOD, "force": bad})
    assert math.isfinite(estimator.predict(**{**GOOD, "force": np.array([8, 30, 58])}).modulus_pa)
    with GraspStoreWriter(tmp_path / "s", (4, 5), "test") as writer:
        for bad in (True, "50", np.datetime64("2024-01-01")):
            with pytest.raises(ValueError, match="force_n_2: expected a number"):
                writer.append(np.zeros((3, 4, 5, 3)), {**_good_row(0), "force_n_2": bad})
        with pytest.raises(ValueError, match=r"frames must be uint8 .* got dtype int64"):
            writer.append(np.zeros((3, 4, 5, 3), np.int64), _good_row(0))
        writer.append(np.zeros((3, 4, 5, 3)), _good_row(0))


def test_estimator_saturates_frames_like_the_store():
    """Values a little outside [0, 1] are saturated to what the store would hold; frames
    decoded from the store pass unchanged."""
    from tactile_compliance.data.store import frames_from_uint8, frames_to_uint8

    rng = np.random.default_rng(3)
    raw = rng.uniform(0.3, 0.7, (3, 8, 8, 3)).astype(np.float32)
    raw[0, 0, 0] = [1.092, 1.2, -0.037]
    checked, _ = input_checks.check_frames(raw)
    stored = frames_from_uint8(frames_to_uint8(raw))
    np.testing.assert_array_equal(checked[0, 0, 0, 0].numpy(), stored[0, 0, 0])
    assert float(checked.max()) <= float(stored.max())
    levels = np.array([0, 7, 128, 255], np.uint8).repeat(144).reshape(3, 8, 8, 3)
    decoded = frames_from_uint8(levels)
    np.testing.assert_array_equal(input_checks.check_frames(decoded)[0][0].numpy(), decoded)


@pytest.mark.parametrize(
    ("text", "pascals"),
    [
        ("2e5", 2e5),
        ("204kPa", 2.04e5),
        ("204 kPa", 2.04e5),
        ("1.2GPa", 1.2e9),
        ("3.5e4 Pa", 3.5e4),
        ("0.85 MPa", 8.5e5),
        (" 25000 ", 2.5e4),
    ],
)
def test_a_modulus_is_read_in_pa_with_si_prefixes(text: str, pascals: float) -> None:
    assert plausibility.parse_pascals(text) == pytest.approx(pascals, rel=1e-12)


@pytest.mark.parametrize("text", ["204kPx", "25 k", "3mPa", "soft", "", "1e5 Pa Pa", "2,5e4"])
def test_a_modulus_that_is_no_number_of_pa_is_refused_with_the_forms(text: str) -> None:
    with pytest.raises(ValueError, match=r"give Pa as a number .* kPa, MPa or GPa"):
        plausibility.parse_pascals(text)
