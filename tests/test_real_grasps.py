"""Real grasps (``../shared/reference-data/real/wedge-grasps``): the quirks of the real rig's
readings, ``live`` against ``record`` + ``predict`` on a real video, and the benchmark
``benchmarks/real_grasps.py``.

The real-data tests skip when the files are absent (they are never copied into the
project); the benchmark's helpers are tested on made-up numbers in any case. The
tolerance of "live equals predict" is that of ``tests/test_recording.py``: 1e-5 decades.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import real_grasps
from helpers import ArraySource, cli, json_lines, top10nn_checkpoint, wedge_calibration
from tactile_compliance.acquisition.readings import Readings
from tactile_compliance.acquisition.recording import ObjectInfo, record_grasp
from tactile_compliance.runs.metrics import nmse

#: The grasps whose force is already above the no-contact level at the first frame.
STARTS_IN_CONTACT = {
    "foam_brick_1",
    "foam_brick_2",
    "green_ball_softer_1",
    "green_ball_softer_2",
    "green_ball_softer_3",
    "orange_ball_softest_1",
    "orange_ball_softest_2",
    "orange_ball_softest_3",
}


# ---------------------------------------------------------------------- helpers (no data)
def test_labels_come_from_the_readme_rule_the_table_or_the_command_line(tmp_path):
    (tmp_path / "README.md").write_text(
        "| files | object (dataset label) | E [Pa] |\n|---|---|---|\n"
        "| `green_ball_softer_{1,2,3}` | green_elastic_ball | 9.36e4 |\n"
        "| `golf_ball_{1,2,3}` | golf_ball | 8.50e8 |\n"
    )
    rules = real_grasps.readme_labels(tmp_path / "grasps")  # the parent's README counts
    assert rules == {"green_ball_softer": "green_elastic_ball", "golf_ball": "golf_ball"}
    labels = ["green_elastic_ball", "golf_ball", "foam_brick", "cork"]
    stems = ["green_ball_softer_2", "golf_ball_1", "foam_brick_3", "cork_stopper_1"]
    matched = real_grasps.match_labels(stems, labels, rules, {"cork_stopper": "cork"})
    assert matched == dict(
        zip(stems, ["green_elastic_ball", "golf_ball", "foam_brick", "cork"], strict=True)
    )
    with pytest.raises(real_grasps.BenchmarkError, match=r"cork_stopper_1: no label.*mug_1: label"):
        real_grasps.match_labels([*stems, "mug_1"], labels, rules, {"mug": "mug"})


def test_the_summary_uses_the_projects_metrics():
    grasps = [
        {"object": "a", "true_pa": 1e4, "m": 2e4},
        {"object": "a", "true_pa": 1e4, "m": 5e5},  # 1.7 decades off
        {"object": "b", "true_pa": 1e6, "m": None},  # missing: counts as outside
        {"object": "c", "true_pa": 1e9, "m": 1e8},
        {"object": "d", "true_pa": 1e7, "m": 1e7},
    ]
    s = real_grasps.score(grasps, "m")
    assert s["within_one_decade"] == pytest.approx(3 / 5) and s["n_missing"] == 1
    assert s["nmse"] == pytest.approx(nmse([1e4, 1e4, 1e9, 1e7], [2e4, 5e5, 1e8, 1e7]))
    # Objects a (mean log10 5.0), c (8), d (7) against truths 4, 9, 7: ranks agree.
    assert s["spearman_objects"] == pytest.approx(1.0)
    rows = real_grasps.per_object(grasps, ["m"])
    assert [r["object"] for r in rows] == ["a", "b", "d", "c"]  # by true E
    assert rows[0]["m"] == pytest.approx(1e5) and rows[1]["m"] is None


def test_models_are_named_by_their_run_or_their_own_file():
    names = real_grasps._model_names(
        [
            Path("runs/top10nn-ImageFW-unseen-random-seed0-cf1c812ecd/best.pt"),
            Path("models/seed1.pt"),
            Path("models/seed2.pt"),
            Path("exports/top10nn"),
            Path("other/top10nn/best.pt"),
        ]
    )
    assert names == [
        "top10nn-ImageFW-unseen-random-seed0",
        "seed1",
        "seed2",
        "top10nn",
        "top10nn-2",
    ]


def test_predict_takes_an_exported_directory_like_live(tmp_path):
    """The benchmark's --model is what predict takes: a checkpoint or an export."""
    pytest.importorskip("safetensors")
    from toy_store import make_toy_store

    store = make_toy_store(tmp_path / "store", n_objects=3, grasps=1, size=(72, 72))
    ckpt = top10nn_checkpoint(tmp_path / "m.pt", inputs="ImageFW", size=(72, 72))
    cli("export", ckpt, "--safetensors", tmp_path / "model-dir")
    by_checkpoint = json.loads(cli("predict", ckpt, store.path, "--json"))["predictions"]
    by_export = json.loads(cli("predict", tmp_path / "model-dir", store.path, "--json"))
    assert [p["pred_log10_pa"] for p in by_export["predictions"]] == pytest.approx(
        [p["pred_log10_pa"] for p in by_checkpoint], abs=1e-5
    )


# ---------------------------------------------------------------------- real data
@pytest.fixture(scope="module")
def wedge_grasps(reference_data_dir: Path) -> Path:
    folder = reference_data_dir / "real" / "wedge-grasps"
    if not (folder / "2023-12-06").is_dir():
        pytest.skip(f"{folder} is not present")
    return folder


def _session(wedge_grasps: Path) -> Path:
    return wedge_grasps / "2023-12-06"


def test_the_real_readings_quirks_are_found(wedge_grasps):
    """No spikes in these 15; baselines within +-0.2 N, from the flat ends; 8 grasps start
    in contact (the force above the no-contact level at the first frame)."""
    starts = set()
    for path in sorted(_session(wedge_grasps).glob("*_readings.csv")):
        readings = Readings.from_csv(path)
        assert readings.spikes == [] and np.array_equal(readings.force_n, readings.raw_force_n)
        baseline = readings.baseline
        assert baseline.level_n == pytest.approx(0.0, abs=0.2), path.name
        if baseline.contact_n(readings.force_n[0]) is not None:
            starts.add(path.name.removesuffix("_readings.csv"))
    assert starts == STARTS_IN_CONTACT


def test_a_force_spike_in_a_real_grasp_changes_nothing_but_is_reported(wedge_grasps, tmp_path):
    """-70 N in one frame of the hold: without the handling the capture would end there."""
    from tactile_compliance.acquisition.calibration import SensorCalibration

    video = _session(wedge_grasps) / "golf_ball_1.avi"
    table = pd.read_csv(video.with_name("golf_ball_1_readings.csv"))
    spiked = table.copy()
    frame = int(np.argmax(table.force_n.to_numpy())) + 3
    spiked.loc[frame, "force_n"] = -70.0
    spiked.to_csv(tmp_path / "spiked.csv", index=False)
    calibration = SensorCalibration.load(wedge_calibration(tmp_path, video))
    results = []
    for name, csv in (
        ("clean", video.with_name("golf_ball_1_readings.csv")),
        ("spiked", tmp_path / "spiked.csv"),
    ):
        with calibration.open(f"wedge:{video}") as source:
            results.append(
                record_grasp(
                    source,
                    Readings.from_csv(csv),
                    tmp_path / name,
                    ObjectInfo("golf_ball", 8.5e8),
                    calibration=calibration,
                )
            )
    clean, spike = results
    assert spike.n_frames == clean.n_frames and spike.frame_indices == clean.frame_indices
    # The analytical estimates use every frame's force; the replaced reading is its
    # neighbours' median, within 0.2 N of the clean one here, so they barely move.
    np.testing.assert_allclose(spike.estimates_pa, clean.estimates_pa, rtol=1e-4)
    assert [s["frame"] for s in spike.checks["spikes"]] == [frame]
    replaced = spike.checks["spikes"][0]["replaced_n"]
    assert replaced == pytest.approx(table.force_n[frame], abs=0.2)
    assert any(f"frame {frame}: -70.00 N replaced by" in w for w in spike.warnings)


def test_a_long_real_recording_of_223_frames(wedge_grasps, tmp_path):
    """A real grasp after a long empty lead-in (223 frames in all, as long as the rig's
    longest): the same frames after the lead-in and the same analytical estimates."""
    from tactile_compliance.acquisition.calibration import SensorCalibration
    from tactile_compliance.acquisition.sensors import iter_frames

    video = _session(wedge_grasps) / "purple_ball_hardest_1.avi"
    readings_csv = video.with_name("purple_ball_hardest_1_readings.csv")
    calibration = SensorCalibration.load(wedge_calibration(tmp_path, video))
    import cv2

    capture = cv2.VideoCapture(str(video))
    raw = []
    while (item := capture.read())[0]:
        raw.append(item[1])
    lead = 223 - len(raw)

    table = pd.read_csv(readings_csv)
    force = np.r_[np.full(lead, table.force_n.iloc[0]), table.force_n]
    width = np.r_[np.full(lead, table.width_m.iloc[0]), table.width_m]
    long_readings = Readings(np.arange(223) / 30.0, force, width)
    info = ObjectInfo("purple_elastic_ball", 2.04e5)
    long = record_grasp(
        ArraySource([raw[0]] * lead + raw, calibration.geometry, name="replay"),
        long_readings,
        tmp_path / "long",
        info,
        calibration=calibration,
    )
    with calibration.open(f"wedge:{video}") as source:
        short = record_grasp(
            source,
            Readings.from_csv(readings_csv),
            tmp_path / "short",
            info,
            calibration=calibration,
        )
    assert long.n_frames == short.n_frames + lead > 200
    assert long.frame_indices == [tuple(i + lead for i in f) for f in short.frame_indices]
    np.testing.assert_allclose(long.estimates_pa, short.estimates_pa, rtol=1e-6)
    with ArraySource(
        raw, calibration.geometry, name="replay"
    ) as source:  # the replay gives the video's frames
        frames = [f for _, f in iter_frames(source)]
    with calibration.open(f"wedge:{video}") as source:
        assert all(
            np.array_equal(a, b) for a, (_, b) in zip(frames, iter_frames(source), strict=True)
        )


def test_live_on_a_real_video_equals_record_and_predict(wedge_grasps, tmp_path):
    """The documented path on a real grasp that starts in contact, with an ALL checkpoint
    (so live also computes the analytical estimates from depth maps, as record did)."""

    video = _session(wedge_grasps) / "foam_brick_1.avi"
    readings = video.with_name("foam_brick_1_readings.csv")
    sensor = wedge_calibration(tmp_path, video)
    ckpt = top10nn_checkpoint(tmp_path / "m.pt", inputs="ALL", size=(72, 72))
    data, store = tmp_path / "data", tmp_path / "store"
    common = ["--readings", readings, "--calibration", sensor]
    recorded = json.loads(
        cli(
            "record",
            f"wedge:{video}",
            "--out",
            data,
            "--object",
            "foam_brick",
            "--modulus",
            3e5,
            *common,
            "--json",
        )
    )
    assert any("starts in contact" in w for w in recorded["warnings"])
    assert all(np.isfinite(recorded["estimates_pa"]))
    cli("import", "burgess", data, "--out", store, "--fingers", "markerless")
    predicted = json.loads(cli("predict", ckpt, store, "--json"))
    rows = {p["augmentation"]: p for p in predicted["predictions"]}
    assert len(rows) == recorded["augmentations"]
    events = json_lines(cli("live", ckpt, f"wedge:{video}", *common, "--json"))
    warnings = [e["reason"] for e in events if e["event"] == "warning"]
    assert any("starts in contact" in w for w in warnings)
    final = [e for e in events if e.get("final")]
    assert len(final) == 1 and events[-1] is final[0]
    assert final[0]["frame_indices"] == recorded["frame_indices"][0]
    assert final[0]["frames_seen"] == recorded["n_frames"]
    assert final[0]["log10_modulus_pa"] == pytest.approx(rows[0]["pred_log10_pa"], abs=1e-5)


def _subset(wedge_grasps: Path, tmp_path: Path, stems) -> Path:
    """A recordings folder of a few real grasps, by symbolic links (nothing copied)."""
    root = tmp_path / "recordings"
    (root / "session").mkdir(parents=True)
    (root / "wedge_config").symlink_to(wedge_grasps / "wedge_config")
    (tmp_path / "README.md").symlink_to(wedge_grasps.parent / "README.md")
    for stem in stems:
        for name in (f"{stem}.avi", f"{stem}_readings.csv"):
            (root / "session" / name).symlink_to(_session(wedge_grasps) / name)
    return root


def test_the_benchmark_runs_the_user_path(wedge_grasps, object_table_csv, tmp_path):
    """Two real grasps of two objects with a tiny untrained checkpoint (its numbers mean
    nothing; the test checks the plumbing): the analytical estimates are those ``record``
    stored, the model's those of ``predict`` (augmentation 0)."""

    recordings = _subset(wedge_grasps, tmp_path, ["golf_ball_1", "green_ball_softer_2"])
    (tmp_path / "tiny").mkdir()
    ckpt = top10nn_checkpoint(tmp_path / "tiny" / "best.pt", inputs="ImageFW", size=(72, 72))
    out = tmp_path / "out"
    code = real_grasps.main(
        [
            "--recordings",
            str(recordings),
            "--objects",
            str(object_table_csv),
            "--out",
            str(out),
            "--model",
            str(ckpt),
        ]
    )
    assert code == 0
    result = json.loads((out / "real_grasps.json").read_text())
    assert (out / "real_grasps.png").stat().st_size > 10_000
    assert result["estimators"] == ["elastic", "hertz", "tiny"]
    by_stem = {g["recording"]: g for g in result["grasps"]}
    assert by_stem["green_ball_softer_2"]["object"] == "green_elastic_ball"
    assert by_stem["golf_ball_1"]["true_pa"] == pytest.approx(8.5e8)
    assert any("starts in contact" in w for w in by_stem["green_ball_softer_2"]["warnings"])
    store = out / "work" / "store"
    predicted = json.loads(cli("predict", ckpt, store, "--json"))["predictions"]
    for p in predicted:
        g = next(
            g for g in result["grasps"] if (g["object"], g["grasp"]) == (p["object"], p["grasp"])
        )
        assert p["pred_log10_pa"] in g["tiny_augmentations_log10"]
        if p["augmentation"] == 0:
            assert g["tiny"] == pytest.approx(p["pred_pa"], rel=1e-9)
    stored = out / "work" / "dataset" / "golf_ball" / "grasp=0" / "augmentation=0"
    from tactile_compliance.data.safe_pickle import load_numpy_pickle

    assert by_stem["golf_ball_1"]["elastic"] == pytest.approx(
        float(load_numpy_pickle(stored / "elastic_estimate.pkl"))
    )
    assert result["commands"][0].startswith("tactile-compliance calibrate wedge:")
    # A fresh --out only.
    assert real_grasps.main(["--recordings", str(recordings), "--out", str(out)]) == 2


def test_the_benchmark_scores_adapt_leave_one_object_out(wedge_grasps, object_table_csv, tmp_path):
    """``--adapt MODEL`` runs `adapt` on the benchmark's own store and scores each grasp by
    the map fitted on the other objects' grasps: the same numbers as the library's
    leave-one-object-out on the model's zero-shot predictions of the same grasps."""
    import math

    from tactile_compliance.inference.adapt import GraspPrediction, leave_one_object_out
    from tactile_compliance.runs.output_calibration import DEFAULT_RIDGE

    stems = ["golf_ball_1", "green_ball_softer_2", "purple_ball_hardest_1"]
    recordings = _subset(wedge_grasps, tmp_path, stems)
    (tmp_path / "tiny").mkdir()
    ckpt = top10nn_checkpoint(tmp_path / "tiny" / "best.pt", inputs="ImageFW", size=(72, 72))
    out = tmp_path / "out"
    result = real_grasps.run(
        out, recordings, object_table_csv, models=[ckpt], adapt=[ckpt], log=lambda *_: None
    )
    assert result["estimators"] == ["elastic", "hertz", "tiny", "tiny-adapted-loo"]
    assert "leave-one-object-out" in result["names"]["tiny-adapted-loo"]
    assert (out / "work" / "tiny-adapted-loo" / "best.pt").is_file()
    grasps = result["grasps"]
    own = [
        GraspPrediction(g["object"], g["grasp"], g["true_pa"], math.log10(g["tiny"]))
        for g in grasps
    ]
    expected = leave_one_object_out(own, DEFAULT_RIDGE)
    for g, log10_pa in zip(grasps, expected, strict=True):
        assert math.log10(g["tiny-adapted-loo"]) == pytest.approx(log10_pa, abs=1e-6)
    assert result["summary"]["tiny-adapted-loo"]["n_missing"] == 0
    assert any(c.startswith("tactile-compliance adapt ") for c in result["commands"])


@pytest.mark.slow
def test_the_benchmark_on_all_real_grasps(wedge_grasps, object_table_csv, tmp_path):
    """All 15 grasps (20-80 s on the shared 2-core machine): every recording goes through,
    every object is matched."""
    result = real_grasps.run(tmp_path / "out", wedge_grasps, object_table_csv, log=lambda *_: None)
    assert len(result["grasps"]) == 15 and len(result["objects"]) == 5
    assert {g["object"] for g in result["grasps"]} == {
        "foam_brick",
        "golf_ball",
        "green_elastic_ball",
        "orange_elastic_ball",
        "purple_elastic_ball",
    }
    starts = {g["recording"] for g in result["grasps"] if g["checks"]["first_frame_contact_n"]}
    assert starts == STARTS_IN_CONTACT
    for key in ("elastic", "hertz"):
        assert 0 <= result["summary"][key]["within_one_decade"] <= 1


def test_record_with_a_rig_reports_the_rig_corrected_estimates_next_to_the_two(
    wedge_grasps, object_table_csv, tmp_path
):
    """`record --rig wedge-2023` (through the benchmark's --rig): the dataset's two estimates
    as without a rig, and the rig-corrected pair next to them; the golf ball's closure is
    mostly the rig's, so taking it out reads it stiffer."""
    recordings = _subset(wedge_grasps, tmp_path, ["golf_ball_1"])
    plain = real_grasps.run(tmp_path / "plain", recordings, object_table_csv, log=lambda *_: None)
    rig = real_grasps.run(
        tmp_path / "rig", recordings, object_table_csv, rig="wedge-2023", log=lambda *_: None
    )
    assert rig["estimators"] == ["elastic", "hertz", "elastic_rig", "hertz_rig"]
    before, after = plain["grasps"][0], rig["grasps"][0]
    assert (after["elastic"], after["hertz"]) == (before["elastic"], before["hertz"])
    assert after["elastic_rig"] > 2 * after["elastic"] and after["hertz_rig"] > after["hertz"]
    assert any("--rig wedge-2023" in c for c in rig["commands"])


def test_live_runs_a_depth_map_model_on_a_real_video_as_predict_does(wedge_grasps, tmp_path):
    """A DepthFW checkpoint on a replayed real Wedge video: live computes each frame's
    depth map and resizes it as the importer stores it, so its final estimate is
    predict's on the recorded grasp (measured equal; asserted to 1e-6 decades)."""
    import torch

    from tactile_compliance.data.normalisation import NormalisationConstants
    from tactile_compliance.models import create_model
    from tactile_compliance.runs.checkpoint import save_checkpoint
    from tactile_compliance.runs.run_inputs import RunInputs

    video = _session(wedge_grasps) / "golf_ball_1.avi"
    readings = video.with_name("golf_ball_1_readings.csv")
    sensor = wedge_calibration(tmp_path, video)
    torch.manual_seed(0)
    run_inputs = RunInputs((72, 72), (250, 350), NormalisationConstants(), "DepthFW")
    ckpt = save_checkpoint(
        tmp_path / "depth.pt",
        create_model("top10nn", inputs="DepthFW"),
        run_inputs=run_inputs,
        config={},
        seed=0,
    )
    data, store = tmp_path / "data", tmp_path / "store"
    common = ["--readings", readings, "--calibration", sensor]
    cli(
        "record",
        f"wedge:{video}",
        "--out",
        data,
        "--object",
        "golf_ball",
        "--modulus",
        8.5e8,
        *common,
    )
    cli("import", "burgess", data, "--out", store, "--fingers", "markerless")
    predicted = json.loads(cli("predict", ckpt, store, "--json"))
    rows = {p["augmentation"]: p for p in predicted["predictions"]}
    events = json_lines(cli("live", ckpt, f"wedge:{video}", *common, "--json"))
    final = [e for e in events if e.get("final")]
    assert len(final) == 1
    assert final[0]["log10_modulus_pa"] == pytest.approx(rows[0]["pred_log10_pa"], abs=1e-6)


def test_the_figure_has_one_panel_per_family_with_short_labels(tmp_path):
    """Issue 42: 14 legend entries over overlapping markers became one panel per family
    (analytical, then each model), each member labelled by its input strategy."""
    models = [
        f"{m}-{i}-unseen-random-seed0" for m in ("top10nn", "res_tf") for i in ("Image", "ALL")
    ] + ["scalar_mlp-FW-unseen-random-seed0"]
    keys = ["elastic", "hertz", *models]
    rows = [
        {"object": name, "true_pa": true, "grasps": 3, **{k: true * 3.0 for k in keys}}
        for name, true in (("foam", 3e5), ("golf", 8.5e8))
    ]
    names = {"elastic": "elastic (analytical)", "hertz": "Hertz (analytical)"}
    result = {
        "estimators": keys,
        "names": names | {m: m for m in models},
        "objects": rows,
        "grasps": [{}] * 6,
    }
    panels = real_grasps.figure_panels(result)
    assert [title for title, _ in panels] == ["Analytical", "Top10NN", "Res-Tf", "Scalar MLP"]
    assert [label for _, label in panels[1][1]] == ["Image", "ALL"]
    # Issue 39: rows beyond the paper's four strategies say so, in the figure and tables.
    assert [label for _, label in panels[3][1]] == ["FW (beyond the paper)"]
    assert real_grasps.beyond_paper_mark(models[0]) == models[0]
    assert real_grasps.beyond_paper_mark(models[-1]) == f"{models[-1]} (beyond the paper)"
    assert real_grasps.beyond_paper_mark("adapted-thing") == "adapted-thing"
    assert panels[0][1] == [("elastic", "elastic (analytical)"), ("hertz", "Hertz (analytical)")]
    path = real_grasps.draw_figure(result, tmp_path / "real_grasps.png")
    assert path.read_bytes().startswith(b"\x89PNG")
