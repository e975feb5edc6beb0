"""The model-free estimate: ``estimate`` prints the analytical estimates ``record`` stores,
``live SOURCE`` (no checkpoint) streams them to the same final values, and the accuracy
that ``estimate`` quotes is what ``benchmarks/real_estimates.py`` measures on the real
Wedge grasps (skipped when they are absent).

Tolerances: ``estimate`` and ``record`` run the same function on the same decoded frames,
so they agree exactly; ``live`` computes each frame's depth map alone rather than in one
batch and gives the estimator the frames from the press on rather than from frame 0, so
1e-9 relative.
"""

from __future__ import annotations

import json
import math

import pytest

from helpers import cli, make_replay_grasp, runner
from tactile_compliance.acquisition.estimates import REAL_WEDGE_ACCURACY, accuracy_statement
from tactile_compliance.cli import app
from tactile_compliance.physics.estimators import WEDGE_UNITS, SensorUnits

SIZE = (250, 350)  # the dataset's frame size: big enough for both estimates


@pytest.fixture(scope="module")
def grasp(tmp_path_factory):

    return make_replay_grasp(tmp_path_factory.mktemp("estimate"), SIZE)


def test_estimate_prints_the_estimates_record_stores(grasp, tmp_path):
    source = f"video:{grasp['video']}"
    estimated = json.loads(cli("estimate", source, "--readings", grasp["readings"], "--json"))
    recorded = json.loads(
        cli(
            "record", source, "--readings", grasp["readings"], "--out", tmp_path / "data",
            "--object", "thing", "--modulus", grasp["modulus_pa"], "--json",
        )
    )  # fmt: skip
    assert estimated["estimates_pa"] == recorded["estimates_pa"]
    assert all(v is not None and v > 0 for v in estimated["estimates_pa"])
    assert [estimated["elastic_pa"], estimated["hertz_pa"]] == estimated["estimates_pa"]
    assert estimated["frame_indices"] == recorded["frame_indices"][0]
    assert estimated["units"] == WEDGE_UNITS.to_dict()
    assert estimated["accuracy"]["grasps"] == REAL_WEDGE_ACCURACY["grasps"]
    text = cli("estimate", source, "--readings", grasp["readings"])
    elastic, hertz = estimated["estimates_pa"]
    assert f"elastic E {elastic:.4g} Pa, Hertz E* {hertz:.4g} Pa" in text
    assert "15 real Wedge grasps of only 5 objects" in text and "9/15" in text
    assert not (tmp_path / "nothing").exists()


def test_estimate_with_a_rig_adds_the_rig_corrected_estimates_record_reports(grasp, tmp_path):
    source = f"video:{grasp['video']}"
    readings = ["--readings", grasp["readings"], "--rig", "dataset"]  # the grasp's own rig
    estimated = json.loads(cli("estimate", source, *readings, "--json"))
    recorded = json.loads(
        cli(
            "record", source, *readings, "--out", tmp_path / "data", "--object", "thing",
            "--modulus", grasp["modulus_pa"], "--json",
        )
    )  # fmt: skip
    rig = estimated["rig_corrected_pa"]
    assert rig == recorded["rig_corrected_pa"] and all(v is not None and v > 0 for v in rig)
    assert rig != estimated["estimates_pa"]  # the closure taken out changes them
    # Taking out the rig's own closure leaves less of it to the object: stiffer estimates.
    assert rig[0] > estimated["estimates_pa"][0]
    assert "rig-corrected with the wedge-2023 rig" in estimated["accuracy"]["statement"]
    text = cli("estimate", source, *readings)
    assert f"Rig-corrected elastic E {rig[0]:.4g} Pa, Hertz E* {rig[1]:.4g} Pa" in text
    assert (
        json.loads(cli("estimate", source, "--readings", grasp["readings"], "--json"))[
            "rig_corrected_pa"
        ]
        is None
    )
    # A wrong rig is refused before the source is read.
    result = runner.invoke(app, ["estimate", "video:/no/such.avi", "--rig", "wedg-2023"])
    assert result.exit_code != 0 and "unknown rig 'wedg-2023'" in result.output


def test_estimate_without_readings_or_with_millimetres_says_why(grasp, tmp_path):
    result = runner.invoke(app, ["estimate", f"video:{grasp['video']}"])
    assert result.exit_code == 2 and "--readings CSV is required" in result.output
    import pandas as pd

    table = pd.read_csv(grasp["readings"])
    table["width_m"] *= 1000
    table.to_csv(tmp_path / "mm.csv", index=False)
    result = runner.invoke(
        app, ["estimate", f"video:{grasp['video']}", "--readings", str(tmp_path / "mm.csv")]
    )
    assert result.exit_code == 2 and "millimetres" in result.output, result.output


def test_live_without_a_checkpoint_streams_the_same_estimates(grasp):
    source = f"video:{grasp['video']}"
    estimated = json.loads(cli("estimate", source, "--readings", grasp["readings"], "--json"))
    result = runner.invoke(app, ["live", source, "--readings", str(grasp["readings"]), "--json"])
    assert result.exit_code == 0, result.output
    events = [json.loads(line) for line in result.stdout.splitlines()]
    # Without --calibration the units are the Wedge's, and live says so in one line.
    said = [line for line in result.stderr.splitlines() if "no --calibration" in line]
    assert len(said) == 1 and "the Wedge's pixel density" in said[0], result.stderr
    estimates = [e for e in events if e["event"] == "estimate"]
    assert len(estimates) >= 2 and not estimates[0]["final"] and estimates[-1]["final"]
    final = estimates[-1]
    assert final["estimates_pa"] == pytest.approx(estimated["estimates_pa"], rel=1e-9)
    assert final["frame_indices"] == estimated["frame_indices"]
    assert "modulus_pa" not in final  # no model, no single modulus
    text = cli("live", source, "--readings", grasp["readings"]).splitlines()
    assert text[-1].startswith("final       elastic E = ") and "Hertz E* = " in text[-1]
    assert "rig-corrected" not in text[-1] and final["rig_corrected_pa"] is None


def test_live_with_a_rig_streams_the_rig_corrected_estimates_of_estimate(grasp, tmp_path):
    source = f"video:{grasp['video']}"
    readings = ["--readings", grasp["readings"], "--rig", "dataset"]
    estimated = json.loads(cli("estimate", source, *readings, "--json"))
    result = runner.invoke(app, ["live", source, *map(str, readings), "--json"])
    assert result.exit_code == 0, result.output
    events = [json.loads(line) for line in result.stdout.splitlines()]
    final = [e for e in events if e["event"] == "estimate"][-1]
    assert final["final"] and final["estimates_pa"] == pytest.approx(
        estimated["estimates_pa"], rel=1e-9
    )
    assert final["rig_corrected_pa"] == pytest.approx(estimated["rig_corrected_pa"], rel=1e-9)
    assert "rig-corrected elastic E = " in cli("live", source, *readings).splitlines()[-1]
    # A model gives its own estimate: --rig with a checkpoint is refused before it loads.
    model = tmp_path / "best.pt"
    model.write_bytes(b"not read")
    result = runner.invoke(app, ["live", str(model), source, *map(str, readings)])
    assert result.exit_code == 2 and "--rig adds the rig-corrected" in result.output


def test_live_with_a_model_in_place_of_the_source_names_the_mistake(tmp_path):
    result = runner.invoke(app, ["live", str(tmp_path / "best.pt"), "--readings", "r.csv"])
    assert result.exit_code == 2
    assert "is a model, not a frame source: give CHECKPOINTS... and then SOURCE" in (result.output)


def test_the_accuracy_statement_says_what_it_covers():
    text = accuracy_statement()
    assert "15 real Wedge grasps of only 5 objects" in text and "Not measured" not in text
    mini = SensorUnits("calibrated", 12.5)
    assert "Not measured in this sensor's units" in accuracy_statement(mini)


def test_the_quoted_accuracy_is_what_the_benchmark_measures(reference_data_dir):
    """``REAL_WEDGE_ACCURACY`` against a fresh run of ``benchmarks/real_estimates.py``."""
    import real_estimates

    recordings = reference_data_dir / "real" / "wedge-grasps"
    if not (recordings / "2023-12-06").is_dir():
        pytest.skip(f"{recordings} is not present")
    result = real_estimates.run(
        recordings, reference_data_dir / "dataset_objects_and_compliance.csv", log=lambda _: None
    )
    quoted = REAL_WEDGE_ACCURACY
    assert (result["n_grasps"], result["n_objects"]) == (quoted["grasps"], quoted["objects"])
    truths = [g["true_pa"] for g in result["grasps"]]
    assert [min(truths), max(truths)] == pytest.approx(quoted["true_range_pa"], rel=1e-3)
    for key in ("elastic", "hertz", "elastic_rig", "hertz_rig"):
        measured = result["summary"][key]
        within = measured["within_one_decade"] * measured["n_grasps"]
        assert math.isclose(within, quoted[key]["within_one_decade"]), key
        assert measured["mae_decades"] == pytest.approx(quoted[key]["mae_decades"], abs=0.005)
        assert measured["spearman_objects"] == pytest.approx(
            quoted[key]["spearman_objects"], abs=0.005
        )
