"""Importer for the GelSight Young's-modulus layout: values, labels, bad input, safety."""

from __future__ import annotations

import os
import pickle

import numpy as np
import pandas as pd
import pytest

from burgess_tree import OBJECTS, dump, write_tree
from tactile_compliance.data.burgess import import_burgess
from tactile_compliance.data.import_report import DataImportError, ImportPathError
from tactile_compliance.data.store import GraspStore


def _import(src, out, **kwargs):
    return import_burgess(src, out, progress=False, **kwargs)


def test_every_value_is_imported(tmp_path):
    written = write_tree(tmp_path / "src")
    report = _import(tmp_path / "src", tmp_path / "store")
    assert report.problems == []
    store = GraspStore.open(tmp_path / "store")
    # 3 objects x 2 grasps x 2 augmentations x 2 fingers
    assert len(store) == report.samples_imported == 24
    assert report.objects_imported == 3
    for row in store.samples.itertuples():
        values = written[(row.object, row.grasp, row.augmentation)]
        modulus, material, shape = OBJECTS[row.object]
        assert (row.modulus_pa, row.material, row.shape) == (modulus, material, shape)
        assert [row.force_n_0, row.force_n_1, row.force_n_2] == values["forces.pkl"].tolist()
        assert [row.width_m_0, row.width_m_1, row.width_m_2] == values["widths.pkl"].tolist()
        assert row.elastic_estimate_pa == float(values["elastic_estimate.pkl"])
        assert row.hertz_estimate_pa == float(values["hertz_estimate.pkl"])
        image_file, depth_file = (
            ("RGB.pkl", "depth.pkl")
            if row.finger == "markerless"
            else ("RGB_markers.pkl", "depth_markers.pkl")
        )
        expected_depth = values[depth_file].reshape(3, -1).max(axis=1)
        assert np.allclose(
            [row.depth_max_mm_0, row.depth_max_mm_1, row.depth_max_mm_2], expected_depth
        )
        # BGR in the file, RGB in the store: channel 0 of the store is channel 2 of the file.
        bgr = values[image_file]
        frames = store.load_frames(row.sample_id)[0]
        assert np.abs(frames[..., 0] - bgr[..., 2]).max() <= 0.5 / 255 + 1e-6
        assert np.abs(frames[..., 2] - bgr[..., 0]).max() <= 0.5 / 255 + 1e-6
        assert row.source_path.endswith(
            f"{row.object}/grasp={row.grasp}/augmentation={row.augmentation}/{image_file}"
        )


def test_one_finger_and_resize(tmp_path):
    write_tree(tmp_path / "src")
    _import(tmp_path / "src", tmp_path / "store", fingers="markers", image_size=(6, 8))
    store = GraspStore.open(tmp_path / "store")
    assert len(store) == 12 and set(store.samples["finger"]) == {"markers"}
    assert store.frames.shape == (12, 3, 6, 8, 3)
    assert store.header.creation_parameters["source_image_size"] == [12, 16]


def test_labels_from_object_table(tmp_path):
    write_tree(tmp_path / "src", metadata=False)
    table = pd.DataFrame(
        {
            "n": [1, 2],
            "Label": ["foam_block", "rubber_ball"],
            "Shape": ["Irregular", "Sphere"],
            "Material": ["Foam", "Rubber"],
            "Modulus [Pa]": [3.3e4, 9.9e5],
        }
    )
    table.to_csv(tmp_path / "objects.csv", index=False)
    report = _import(tmp_path / "src", tmp_path / "store", object_table=tmp_path / "objects.csv")
    store = GraspStore.open(tmp_path / "store")
    by_object = store.samples.groupby("object")[["modulus_pa", "shape"]].first()
    assert by_object.loc["foam_block"].tolist() == [3.3e4, "Irregular"]
    assert by_object.loc["rubber_ball"].tolist() == [9.9e5, "Sphere"]
    # steel_rod has no metadata and is absent from the table: skipped and reported.
    assert any("absent from the object table" in r for _, r in report.problems)
    assert "steel_rod" not in set(store.samples["object"])


def test_real_object_table_is_read(tmp_path, object_table_csv):
    from tactile_compliance.data.object_table import read_object_table

    table = read_object_table(object_table_csv)
    assert len(table) == 287
    assert (table["modulus_pa"] > 0).sum() == 286
    assert table["material"].value_counts()["Rubber"] == 82


def test_bad_input_is_skipped_and_reported(tmp_path):
    src = tmp_path / "src"
    write_tree(src)
    base = src / "foam_block" / "grasp=0"
    (base / "augmentation=0" / "forces.pkl").unlink()  # missing file
    (base / "augmentation=1" / "RGB.pkl").write_bytes(
        (base / "augmentation=1" / "RGB.pkl").read_bytes()[:100]  # truncated pickle
    )
    dump(
        src / "rubber_ball" / "grasp=0" / "augmentation=0" / "RGB_markers.pkl",
        np.zeros((3, 12, 16)),
    )  # wrong shape
    widths = np.array([0.05, np.nan, 0.04])
    dump(src / "rubber_ball" / "grasp=1" / "augmentation=0" / "widths.pkl", widths)  # NaN
    (src / "steel_rod" / "metadata.json").write_text('{"youngs_modulus": -5, "material": "Metal"}')
    report = _import(src, tmp_path / "store")
    reasons = "\n".join(f"{p}: {r}" for p, r in report.problems)
    assert "missing file: forces.pkl" in reasons
    assert "corrupt pickle: RGB.pkl" in reasons
    assert "wrong array shape: RGB_markers.pkl" in reasons
    assert "non-finite values: widths.pkl" in reasons
    assert "invalid modulus: -5" in reasons
    counts = report.reasons()
    assert counts["missing file"] == 1 and counts["invalid modulus"] == 1
    store = GraspStore.open(tmp_path / "store")
    # foam: 8 - 2 (no forces) - 1 (truncated markerless); rubber: 8 - 1 - 2; steel: 0
    assert len(store) == 5 + 5
    assert "steel_rod" not in set(store.samples["object"])
    assert "Skipped" in report.format()


@pytest.mark.parametrize(
    ("value", "kind"), [('"1e6"', "text"), ("true", "a boolean"), ("[1e6]", "list")]
)
def test_a_modulus_that_is_not_a_json_number_is_never_cast(tmp_path, value, kind):
    write_tree(tmp_path / "src")
    meta = tmp_path / "src" / "rubber_ball" / "metadata.json"
    meta.write_text('{"youngs_modulus": ' + value + ', "material": "Rubber"}')
    report = _import(tmp_path / "src", tmp_path / "store")
    assert next(r for _, r in report.problems if "invalid modulus" in r).endswith(
        f"is {kind}, not a JSON number (text and booleans are never cast)"
    )
    assert report.objects_imported == 2
    assert "rubber_ball" not in set(GraspStore.open(tmp_path / "store").samples["object"])


def test_missing_modulus_in_metadata(tmp_path):
    write_tree(tmp_path / "src")
    (tmp_path / "src" / "rubber_ball" / "metadata.json").write_text('{"material": "Rubber"}')
    report = _import(tmp_path / "src", tmp_path / "store")
    assert any("invalid modulus: None" in r for _, r in report.problems)
    assert report.objects_imported == 2


def test_strict_stops_at_first_problem_and_writes_nothing(tmp_path):
    write_tree(tmp_path / "src")
    (tmp_path / "src" / "foam_block" / "grasp=1" / "augmentation=0" / "widths.pkl").unlink()
    with pytest.raises(DataImportError, match=r"missing file: widths\.pkl"):
        _import(tmp_path / "src", tmp_path / "store", strict=True)
    assert not (tmp_path / "store").exists()
    assert [p.name for p in tmp_path.iterdir()] == ["src"]


class _CreatesFile:
    def __init__(self, path: str) -> None:
        self.path = path

    def __reduce__(self):
        return (os.system, (f"touch {self.path}",))


def test_malicious_pickle_is_rejected_not_executed(tmp_path):
    write_tree(tmp_path / "src")
    marker = tmp_path / "pwned"
    target = tmp_path / "src" / "foam_block" / "grasp=0" / "augmentation=0" / "forces.pkl"
    target.write_bytes(pickle.dumps(_CreatesFile(str(marker))))
    report = _import(tmp_path / "src", tmp_path / "store")
    assert not marker.exists()
    assert any("unsafe pickle rejected" in r for _, r in report.problems)


def test_existing_store_needs_overwrite(tmp_path):
    write_tree(tmp_path / "src")
    _import(tmp_path / "src", tmp_path / "store", fingers="markerless")
    with pytest.raises(FileExistsError, match="--overwrite"):
        _import(tmp_path / "src", tmp_path / "store")
    assert len(GraspStore.open(tmp_path / "store")) == 12  # untouched
    _import(tmp_path / "src", tmp_path / "store", overwrite=True)
    assert len(GraspStore.open(tmp_path / "store")) == 24


def test_nothing_importable_is_an_error(tmp_path):
    (tmp_path / "src").mkdir()
    with pytest.raises(DataImportError, match="no object directories"):
        _import(tmp_path / "src", tmp_path / "store")
    with pytest.raises(DataImportError, match="not found"):
        _import(tmp_path / "nope", tmp_path / "store")


def test_missing_estimate_is_kept_as_nan(tmp_path):
    write_tree(tmp_path / "src", grasps=1, augmentations=1)
    (tmp_path / "src" / "foam_block" / "grasp=0" / "augmentation=0" / "hertz_estimate.pkl").unlink()
    _import(tmp_path / "src", tmp_path / "store")
    samples = GraspStore.open(tmp_path / "store").samples.set_index("object")
    assert samples.loc["foam_block", "hertz_estimate_pa"].isna().all()
    assert samples.loc["steel_rod", "hertz_estimate_pa"].notna().all()


def test_source_is_synthetic_for_generated_trees(tmp_path):
    write_tree(tmp_path / "src", grasps=1, augmentations=1)
    _import(tmp_path / "src", tmp_path / "real")
    assert GraspStore.open(tmp_path / "real").header.source == "burgess"
    (tmp_path / "src" / "generation.json").write_text('{"analytical_estimator": "contact"}')
    _import(tmp_path / "src", tmp_path / "generated")
    generated = GraspStore.open(tmp_path / "generated")
    assert (
        generated.header.source == "synthetic" and generated.analytical_estimator.name == "contact"
    )
    # A pre-release generator's manifest named no estimator: refused, nothing written.
    (tmp_path / "src" / "generation.json").write_text("{}")
    with pytest.raises(ImportPathError, match="names no analytical_estimator"):
        _import(tmp_path / "src", tmp_path / "old")
    assert not (tmp_path / "old").exists()


def test_clipped_frame_values_are_counted_in_the_report(tmp_path):
    # Frames whose differences exceed what uint8 holds (-127..+128 grey levels): a few
    # saturated pixels pass the frame rule, and the report says how many were clipped.
    written = write_tree(tmp_path / "src", grasps=1, augmentations=1)
    rgb = written[("rubber_ball", 0, 0)]["RGB.pkl"].copy()
    rgb[0, 0, :5, 2] = 1.2  # five values far above +128 levels
    rgb[1, 2, :3, 0] = -0.003  # three values just below -127 levels (k = -128)
    rgb[2, 3, 0, 1] = 128 / 255 + 0.5  # +128 levels: the largest that fits, not clipped
    rgb[2, 3, 1, 1] = -127 / 255 + 0.5  # -127 levels: the smallest that fits
    dump(tmp_path / "src" / "rubber_ball" / "grasp=0" / "augmentation=0" / "RGB.pkl", rgb)
    report = _import(tmp_path / "src", tmp_path / "store")
    assert report.problems == [] and report.samples_imported == 6
    assert report.frame_values == 6 * rgb.size
    assert report.clipped_frame_values == 8
    assert report.samples_with_clipped_frames == 1
    assert report.clipped_frame_share == pytest.approx(8 / (6 * rgb.size))
    assert f"Clipped frame values: 8 of {6 * rgb.size:,}" in report.format()
    saved = report.to_dict()
    assert saved["clipped_frame_values"] == 8 and saved["frame_values"] == 6 * rgb.size
    # What the store holds: the clipped values at the ends, the others exact.
    store = GraspStore.open(tmp_path / "store")
    row = store.samples.query("object == 'rubber_ball' and finger == 'markerless'")
    frames = store.load_frames(int(row["sample_id"].iloc[0]))[0]  # RGB: file channel c -> 2-c
    np.testing.assert_allclose(frames[0, 0, :5, 0], 128 / 255 + 0.5, atol=1e-6)
    np.testing.assert_allclose(frames[1, 2, :3, 2], -127 / 255 + 0.5, atol=1e-6)
    np.testing.assert_allclose(frames[2, 3, :2, 1], [128 / 255 + 0.5, -127 / 255 + 0.5], atol=1e-6)


def test_frames_within_range_clip_nothing(tmp_path):
    write_tree(tmp_path / "src", grasps=1, augmentations=1)
    report = _import(tmp_path / "src", tmp_path / "store")
    assert report.frame_values == 6 * 3 * 12 * 16 * 3
    assert report.clipped_frame_values == 0 and report.samples_with_clipped_frames == 0
    assert "Clipped frame values: 0 of" in report.format()


def _markerless_only(root):
    write_tree(root)
    for name in ("RGB_markers.pkl", "depth_markers.pkl"):
        for path in root.rglob(name):
            path.unlink()


def test_a_markerless_only_tree_imports_its_one_finger_with_one_line(tmp_path):
    """What ``record`` writes (no marker finger) imports with the default --fingers both:
    one line says so, not a missing RGB_markers.pkl per sample (issue 42)."""
    _markerless_only(tmp_path / "src")
    report = _import(tmp_path / "src", tmp_path / "store")
    assert report.problems == [] and report.samples_imported == 12
    assert "markerless only: no sample has RGB_markers.pkl" in report.fingers_note
    assert report.fingers_note in report.format()
    store = GraspStore.open(tmp_path / "store")
    assert set(store.samples["finger"]) == {"markerless"}
    with pytest.raises(
        DataImportError, match=r"no sample has RGB_markers\.pkl.*--fingers markerless"
    ):
        _import(tmp_path / "src", tmp_path / "store2", fingers="markers")
    assert not (tmp_path / "store2").exists()


def test_a_tree_with_some_marker_files_missing_still_reports_each(tmp_path):
    write_tree(tmp_path / "src")
    next((tmp_path / "src").rglob("RGB_markers.pkl")).unlink()
    report = _import(tmp_path / "src", tmp_path / "store")
    assert report.fingers_note == "" and len(report.problems) == 1
