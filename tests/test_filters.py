"""Sample filter: each rule removes exactly the rows it should, and says how many."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from burgess_tree import dump, write_tree
from tactile_compliance.config import ExperimentConfig, FilterConfig
from tactile_compliance.data.burgess import import_burgess
from tactile_compliance.data.preprocess import UNKNOWN_GROUND_TRUTH_OBJECTS, filter_samples
from tactile_compliance.data.store import GraspStore


def good_row(obj: str, **changes: object) -> dict:
    """A sample that passes every rule; ``changes`` break one of them."""
    row = {
        "object": obj,
        "grasp": 0,
        "augmentation": 0,
        "finger": "markerless",
        "material": "Rubber",
        "shape": "Sphere",
        "modulus_pa": 1e6,
        "force_n_0": 5.0,
        "force_n_1": 30.0,
        "force_n_2": 60.0,
        "width_m_0": 0.050,
        "width_m_1": 0.048,
        "width_m_2": 0.046,
        "elastic_estimate_pa": 2e6,
        "hertz_estimate_pa": 5e5,
        "depth_max_mm_0": 0.2,
        "depth_max_mm_1": 0.8,
        "depth_max_mm_2": 1.1,
    }
    row.update(changes)
    return row


def table(rows: list[dict]) -> pd.DataFrame:
    df = pd.DataFrame(rows)
    df.insert(0, "sample_id", np.arange(len(df)))
    return df


def burgess_like() -> pd.DataFrame:
    rows = [good_row("keep"), good_row("keep", grasp=1), good_row("keep", finger="markers")]
    rows += [
        good_row("a", hertz_estimate_pa=np.nan),  # 3 missing estimate
        good_row("a", elastic_estimate_pa=np.inf),  # 4 missing estimate
        good_row("a", force_n_2=5.0),  # 5 no force increase (equal)
        good_row("a", force_n_2=np.nan),  # 6 force unverifiable
        good_row("a", width_m_2=0.051),  # 7 no width decrease
        good_row("a", depth_max_mm_2=0.8),  # 8 no depth increase (equal)
        good_row("a"),  # 9 ok, but "a" is then left with one sample
        good_row("apple"),  # 10 unknown ground truth
        good_row("APPLE", grasp=1),  # 11 unknown ground truth (case-insensitive)
        good_row("book", material="Paper"),  # 12 excluded material
        good_row("book", material="paper", grasp=1),  # 13
        good_row("pair"),  # 14 ok
        good_row("pair", grasp=1),  # 15 ok
    ]
    return table(rows)


def test_each_rule_removes_what_it_should():
    kept, report = filter_samples(burgess_like())
    assert kept["sample_id"].tolist() == [0, 1, 2, 14, 15]
    assert report.n_input == 16 and report.n_output == 5
    expected = {
        "exclude_objects": 2,
        "exclude_materials": 2,
        "missing_estimates": 2,
        "no_force_increase": 2,
        "no_width_decrease": 1,
        "no_depth_increase": 1,
        "single_sample_objects": 1,
    }
    for rule, n in expected.items():
        assert report.removed_by(rule) == n, rule
    assert report.rule("fingers").status == "disabled"  # no finger selection given
    assert sum(expected.values()) == report.n_input - report.n_output
    text = str(report)
    assert "16 -> 5" in text and "no_depth_increase" in text
    assert "13 listed, 1 present" in report.rule("exclude_objects").note
    assert report.to_dict()["rules"][1]["removed"] == 2


def test_rules_can_be_switched_off():
    cfg = FilterConfig(
        drop_missing_estimates=False,
        drop_no_force_increase=False,
        drop_no_width_decrease=False,
        drop_no_depth_increase=False,
        drop_single_sample_objects=False,
        exclude_objects=[],
        exclude_materials=[],
    )
    kept, report = filter_samples(burgess_like(), cfg)
    assert len(kept) == 16
    assert all(r.status == "disabled" or r.removed == 0 for r in report.rules)
    assert report.rule("no_force_increase").status == "disabled"


def test_single_sample_rule_runs_after_the_others():
    # Object "x" has two samples, one fails the width rule: the other is then alone.
    df = table(
        [
            good_row("x"),
            good_row("x", grasp=1, width_m_2=0.06),
            good_row("y"),
            good_row("y", grasp=1),
        ]
    )
    kept, report = filter_samples(df)
    assert kept["object"].tolist() == ["y", "y"]
    assert report.removed_by("no_width_decrease") == 1
    assert report.removed_by("single_sample_objects") == 1


def test_shore_data_rules_not_applicable_instead_of_removing_everything():
    rows = [
        good_row(f"BASIC_{h}", grasp=g, material="Silicone", shape="BASIC")
        for h in (20, 40)
        for g in range(3)
    ]
    df = table(rows)
    nan_columns = [
        c for c in df.columns if c.startswith(("force", "width", "depth", "elastic", "hertz"))
    ]
    df[nan_columns] = np.nan
    kept, report = filter_samples(df)
    assert len(kept) == 6
    for rule in (
        "missing_estimates",
        "no_force_increase",
        "no_width_decrease",
        "no_depth_increase",
    ):
        assert report.rule(rule).status == "not applicable"
        assert report.removed_by(rule) == 0
    assert "not applicable" in str(report)


def test_estimate_rule_uses_only_columns_that_have_data():
    # A source with Hertz estimates only: rows are judged on Hertz alone.
    df = table(
        [good_row("p"), good_row("p", grasp=1), good_row("p", grasp=2, hertz_estimate_pa=np.nan)]
    )
    df["elastic_estimate_pa"] = np.nan
    kept, report = filter_samples(df)
    assert kept["sample_id"].tolist() == [0, 1]
    assert report.removed_by("missing_estimates") == 1


def test_fingers_from_experiment_config():
    df = table(
        [
            good_row("q"),
            good_row("q", finger="markers"),
            good_row("q", grasp=1),
            good_row("q", grasp=1, finger="markers"),
        ]
    )
    cfg = ExperimentConfig.model_validate({"data": {"fingers": ["markers"]}})
    kept, report = filter_samples(df, cfg)
    assert kept["finger"].unique().tolist() == ["markers"]
    assert report.removed_by("fingers") == 2


def test_default_exclusion_list_is_the_13_unknown_objects():
    assert len(UNKNOWN_GROUND_TRUTH_OBJECTS) == 13
    assert FilterConfig().exclude_objects == list(UNKNOWN_GROUND_TRUTH_OBJECTS)
    assert FilterConfig().exclude_materials == ["Paper"]


def test_missing_required_column_is_named():
    with pytest.raises(ValueError, match="material"):
        filter_samples(pd.DataFrame({"sample_id": [0], "object": ["a"]}))


# ------------------------------------------------------------------ rule 7: which finger's depth
def two_finger_presses() -> pd.DataFrame:
    """Two presses of "d" with both fingers, and two of "e" (keep "d" countable alone).

    Press (d, 0): the markerless depth rises, the marker finger's does not.
    Press (d, 1): the marker finger's depth rises, the markerless one's does not.
    """
    flat = {"depth_max_mm_1": 0.8, "depth_max_mm_2": 0.8}
    return table(
        [
            good_row("d", grasp=0),  # 0 markerless, rises
            good_row("d", grasp=0, finger="markers", **flat),  # 1 markers, flat
            good_row("d", grasp=1, **flat),  # 2 markerless, flat
            good_row("d", grasp=1, finger="markers"),  # 3 markers, rises
            good_row("e", grasp=0),  # 4
            good_row("e", grasp=0, finger="markers"),  # 5
        ]
    )


def test_depth_rule_judges_both_fingers_on_the_markerless_depth():
    # The published code reads depth.pkl (the markerless finger) for the samples of both
    # fingers, so a press is kept or dropped as a whole, on the markerless finger's depth.
    kept, report = filter_samples(two_finger_presses())
    assert kept["sample_id"].tolist() == [0, 1, 4, 5]
    assert report.removed_by("no_depth_increase") == 2
    assert "markerless finger's depth" in report.rule("no_depth_increase").note


def test_depth_rule_uses_the_marker_depth_when_only_markers_are_used():
    # use_markers="only_markers" in the published code reads depth_markers.pkl.
    cfg = FilterConfig(drop_single_sample_objects=False)  # one finger: single samples
    kept, report = filter_samples(two_finger_presses(), cfg, fingers=["markers"])
    assert kept["sample_id"].tolist() == [3, 5]
    assert report.removed_by("no_depth_increase") == 1


def test_depth_rule_with_markerless_only_ignores_the_marker_depth():
    cfg = FilterConfig(drop_single_sample_objects=False)
    kept, _ = filter_samples(two_finger_presses(), cfg, fingers=["markerless"])
    assert kept["sample_id"].tolist() == [0, 4]


def test_marker_sample_without_a_markerless_sibling_is_judged_on_its_own_depth():
    df = two_finger_presses()
    df = df[df["sample_id"] != 2].reset_index(drop=True)  # press (d, 1) lost its markerless row
    kept, report = filter_samples(df)
    # Sample 3 (markers, rises) now stands alone and keeps its own, rising, depth.
    assert kept["sample_id"].tolist() == [0, 1, 3, 4, 5]
    assert "1 sample(s) without a markerless one" in report.rule("no_depth_increase").note


def test_depth_rule_through_the_importer(tmp_path):
    # Depth files of one press: depth.pkl rises, depth_markers.pkl does not (and the
    # reverse for the other press); the importer keeps each finger's own maxima.
    objects = {"foam_block": (2.0e4, "Foam", "Rectangular")}
    write_tree(tmp_path / "src", objects=objects, grasps=2, augmentations=1)
    rising = np.ones((3, 12, 16)) * np.array([0.0, 1.0, 2.0])[:, None, None]
    flat = np.ones((3, 12, 16)) * np.array([0.0, 1.0, 1.0])[:, None, None]
    press = tmp_path / "src" / "foam_block"
    dump(press / "grasp=0" / "augmentation=0" / "depth.pkl", rising)
    dump(press / "grasp=0" / "augmentation=0" / "depth_markers.pkl", flat)
    dump(press / "grasp=1" / "augmentation=0" / "depth.pkl", flat)
    dump(press / "grasp=1" / "augmentation=0" / "depth_markers.pkl", rising)
    import_burgess(tmp_path / "src", tmp_path / "store", progress=False)
    samples = GraspStore.open(tmp_path / "store").samples
    # Own maxima per finger in the store...
    by = samples.set_index(["grasp", "finger"])
    assert by.loc[(0, "markers"), "depth_max_mm_2"] == 1.0
    assert by.loc[(1, "markers"), "depth_max_mm_2"] == 2.0
    # ...but grasp 0 is kept with both fingers and grasp 1 dropped with both.
    kept, report = filter_samples(samples)
    assert sorted(zip(kept["grasp"], kept["finger"], strict=True)) == [
        (0, "markerless"),
        (0, "markers"),
    ]
    assert report.removed_by("no_depth_increase") == 2
