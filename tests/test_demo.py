"""The one-command demo, end to end in its reduced CI mode.

The demo runs once per module (about 25 s on an idle 2-core machine); the tests read its
output. Numbers in the report are checked against values recomputed here from the run's
own files and the store's raw columns (predictions.csv, split.json, samples.parquet), and
the predictions against the checkpoint run again through the inference API.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import matplotlib.image
import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from tactile_compliance.cli import app
from tactile_compliance.data.store import GraspStore
from tactile_compliance.runs.results import ResultsStore

REPO = Path(__file__).resolve().parents[1]
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
SPAN_DECADES = 9.0  # the default label range, 1e3..1e12 Pa


@pytest.fixture(scope="module")
def demo(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The demo as a user runs it, with --json: in its own process, so that stdout is
    checked at the file descriptor, where a worker's or a library's print would land."""
    out = tmp_path_factory.mktemp("demo") / "demo"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO / "src"), *sys.path])}
    command = [sys.executable, "-m", "tactile_compliance", "demo", "--out", str(out)]
    result = subprocess.run(
        [*command, "--mode", "ci", "--json"],
        capture_output=True,
        text=True,
        env=env,
        timeout=900,
        check=False,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    summary = json.loads(result.stdout)  # the summary and nothing else
    assert summary["out_dir"] == str(out.resolve()) and Path(summary["report"]).is_file()
    assert set(summary["stage_seconds"]) == {"generate", "import", "train", "report"}
    assert [i["source"] for i in summary["imports"]] == ["synthetic", "yuan"]
    assert [(e["cells"], e["completed"], e["failed"]) for e in summary["experiments"]] == [
        (1, 1, 0)
    ]
    assert len(summary["experiments"][0]["summary"]) == 1  # one configuration's mean row
    assert "Experiment table1-quick" in result.stderr  # the stages' text went to stderr
    return out


@pytest.fixture(scope="module")
def demo_run(demo: Path) -> dict:
    rows = ResultsStore(demo / "results").table()
    assert len(rows) == 1  # ci mode: one grid cell
    row = rows.iloc[0].to_dict()
    run_dir = Path(row["run_dir"])
    predictions = pd.read_csv(run_dir / "predictions.csv")
    return {
        "row": row,
        "dir": run_dir,
        "predictions": predictions,
        "test": predictions[predictions["split"] == "test"].reset_index(drop=True),
        "split": json.loads((run_dir / "split.json").read_text()),
        "raw": pd.read_parquet(demo / "stores" / "gelsight" / "samples.parquet"),
    }


def _nmse(true_pa, pred_pa) -> float:
    d = np.log10(np.asarray(pred_pa, float)) - np.log10(np.asarray(true_pa, float))
    return float(np.mean((d / SPAN_DECADES) ** 2))


def _accuracy(true_pa, pred_pa) -> float:
    d = np.log10(np.asarray(pred_pa, float)) - np.log10(np.asarray(true_pa, float))
    return float(np.mean(np.abs(d) <= 1 + 1e-9))


def test_demo_ci_mode_runs_every_layer(demo):
    store = GraspStore.open(demo / "stores" / "gelsight")
    assert store.header.source == "synthetic" and len(store) > 0
    assert GraspStore.open(demo / "stores" / "shore").header.source == "yuan"
    rows = ResultsStore(demo / "results").table()
    assert len(rows) >= 1 and (rows["status"] == "complete").all()
    report = (demo / "report" / "report.html").read_text()
    assert "Table I" in report and "data:image/png;base64" in report
    # The report says why VGG-LSTM and Res-Tf keep frozen random backbones (issue 13).
    assert "fine-tuning does not fit" in (demo / "report" / "report.md").read_text()
    # Re-running continues: nothing is retrained, the same rows stay.
    again = CliRunner().invoke(app, ["demo", "--out", str(demo), "--mode", "ci"])
    assert again.exit_code == 0, again.output
    assert "1 already complete" in again.stdout and "Demo finished" in again.stdout
    assert len(ResultsStore(demo / "results")) == len(rows)


def test_report_json_lists_real_files_with_content(demo):
    summary = json.loads((demo / "report" / "report.json").read_text())
    assert summary["rows"] == summary["complete"] == len(ResultsStore(demo / "results"))
    assert summary["failed"] == 0
    for path in summary["documents"].values():
        assert Path(path).is_file() and Path(path).stat().st_size > 1000, path
    # Figures: the ones the ci grid can make (Table I runs, one store), each a real image.
    assert {"fig5", "learning-curves"} <= set(summary["figures"])
    assert any(key.startswith("fig1-") for key in summary["figures"])
    for key, path in summary["figures"].items():
        data = Path(path).read_bytes()
        assert data[:8] == PNG_MAGIC, key
        pixels = matplotlib.image.imread(path)
        assert min(pixels.shape[:2]) >= 200, (key, pixels.shape)
        # Not a blank canvas: many distinct colours, and ink on a good part of it.
        rgb = (pixels[..., :3].reshape(-1, 3) * 255).astype(np.int64)
        colours = np.unique(rgb[:, 0] * 65536 + rgb[:, 1] * 256 + rgb[:, 2])
        assert len(colours) > 20, (key, len(colours))
        assert np.mean(pixels[..., :3].mean(axis=-1) < 0.9) > 0.02, key
    # Tables: each listed one has its CSV with the expected columns and rows.
    assert set(summary["tables"]) >= {"tableI", "fig5", "groups-nmse"}
    for key in summary["tables"]:
        assert (demo / "report" / "tables" / f"{key}.csv").is_file(), key
    # The skipped parts are said so, naming the preset that makes them.
    notes = "\n".join(summary["notes"])
    for preset in ("`table2`", "`rolling-window`", "`shape-test`", "`new-dataset`"):
        assert preset in notes, preset
    markdown = Path(summary["documents"]["md"]).read_text()
    for figure in summary["figures"].values():
        assert Path(figure).name in markdown


def test_table1_numbers_are_recomputed_from_the_run(demo, demo_run):
    table = pd.read_csv(demo / "report" / "tables" / "tableI.csv")
    assert {"model", "inputs", "condition", "metric", "mean", "std", "n"} <= set(table.columns)
    test, raw = demo_run["test"], demo_run["raw"]
    # The test rows of predictions.csv are exactly the split's test ids.
    assert sorted(test["sample_id"]) == sorted(demo_run["split"]["test_ids"])
    # ... and their true moduli are the store's.
    true = raw.set_index("sample_id").loc[test["sample_id"], "modulus_pa"].to_numpy()
    assert np.allclose(true, test["modulus_pa"])
    expected = {
        ("top10nn", "nmse"): _nmse(true, test["pred_pa"]),
        ("top10nn", "log10_accuracy"): _accuracy(true, test["pred_pa"]),
    }
    # The reference predictors, from the raw columns of the split's train and test rows.
    by_id = raw.set_index("sample_id")
    median = float(np.median(by_id.loc[demo_run["split"]["train_ids"], "modulus_pa"]))
    elastic = by_id.loc[test["sample_id"], "elastic_estimate_pa"].to_numpy(float)
    hertz = by_id.loc[test["sample_id"], "hertz_estimate_pa"].to_numpy(float)
    analytical = np.where(
        np.isfinite(elastic), elastic, np.where(np.isfinite(hertz), hertz, median)
    )
    analytical = np.clip(analytical, 1e2, 1e14)
    expected |= {
        ("ref_median", "nmse"): _nmse(true, np.full(len(true), median)),
        ("ref_median", "log10_accuracy"): _accuracy(true, np.full(len(true), median)),
        ("ref_analytical", "nmse"): _nmse(true, analytical),
        ("ref_analytical", "log10_accuracy"): _accuracy(true, analytical),
    }
    # The scalar reference (gradient-boosted trees on F, W, E) is not refitted here: its
    # cells must carry the run's recorded values.
    row = demo_run["row"]
    expected |= {
        ("ref_scalar_gbr", metric): row[f"ref_scalar_gbr_{metric}"]
        for metric in ("nmse", "log10_accuracy")
    }
    cells = table[table["condition"] == "seen"]
    assert len(cells) == len(expected)
    for (model, metric), value in expected.items():
        got = cells[(cells["model"] == model) & (cells["metric"] == metric)]
        assert len(got) == 1, (model, metric)
        assert got["mean"].iloc[0] == pytest.approx(value, rel=1e-9, abs=1e-12), (model, metric)
        assert int(got["n"].iloc[0]) == 1  # one seed in ci mode
    # The results row says the same (the table reads it).
    assert demo_run["row"]["test_nmse"] == pytest.approx(expected[("top10nn", "nmse")])


def test_fig5_and_group_tables_are_recomputed_from_predictions(demo, demo_run):
    test = demo_run["test"]
    fig5 = pd.read_csv(demo / "report" / "tables" / "fig5.csv")
    assert len(fig5) == 1 and fig5["run_dir"].iloc[0] == str(demo_run["dir"])
    nmse = _nmse(test["modulus_pa"], test["pred_pa"])
    d = np.abs(np.log10(test["pred_pa"]) - np.log10(test["modulus_pa"]))
    assert fig5["nmse"].iloc[0] == pytest.approx(nmse)
    assert fig5["n"].iloc[0] == len(test)
    band = SPAN_DECADES * math.sqrt(nmse)
    assert fig5["inside_band"].iloc[0] == pytest.approx(float(np.mean(d <= band + 1e-9)))
    groups = pd.read_csv(demo / "report" / "tables" / "groups-nmse.csv")
    soft_hard = np.where(test["modulus_pa"] < 2.75e5, "soft", "hard")
    checked = 0
    for grouping, keys in (
        ("material", test["material"]),
        ("shape", test["shape"]),
        ("soft_hard", pd.Series(soft_hard)),
    ):
        assert set(groups.loc[groups["grouping"] == grouping, "group"]) == set(keys), grouping
        for group in set(keys):
            part = test[keys.to_numpy() == group]
            got = groups[(groups["grouping"] == grouping) & (groups["group"] == group)]
            assert got["mean"].iloc[0] == pytest.approx(_nmse(part["modulus_pa"], part["pred_pa"]))
            checked += 1
    assert checked >= 4


def test_predictions_match_the_checkpoint_run_again(demo, demo_run):
    from tactile_compliance.inference.estimator import ComplianceEstimator

    estimator = ComplianceEstimator.from_checkpoint(demo_run["dir"])
    rows = demo_run["predictions"].sample(n=12, random_state=0)
    raw = demo_run["raw"].set_index("sample_id").loc[rows["sample_id"]]
    store = GraspStore.open(demo / "stores" / "gelsight")
    prediction = estimator.predict(
        store.read_samples(rows["sample_id"].to_numpy()),
        force=raw[[f"force_n_{i}" for i in range(3)]].to_numpy(float),
        width=raw[[f"width_m_{i}" for i in range(3)]].to_numpy(float),
        estimates=raw[["elastic_estimate_pa", "hertz_estimate_pa"]].to_numpy(float),
    )
    assert np.allclose(prediction.modulus_pa, rows["pred_pa"], rtol=1e-4)


def test_cli_predict_export_and_experiment_on_the_demo_output(demo, demo_run, tmp_path):
    # The grid commands below add rows and runs: they get copies of the results and runs
    # directories (the store stays where it is: it is part of each cell's identity).
    out = tmp_path / "demo"
    for name in ("results", "runs"):
        shutil.copytree(demo / name, out / name)
    runner = CliRunner()
    run_dir = str(demo_run["dir"])
    store = demo / "stores" / "gelsight"
    predicted = runner.invoke(app, ["predict", run_dir, str(store), "--json"])
    assert predicted.exit_code == 0, predicted.output
    report = json.loads(predicted.output)
    summary = report["summary"]
    assert summary["n_predicted"] + summary["n_skipped"] == len(demo_run["raw"])
    # Skipped: exactly the samples an ALL model cannot take (a missing estimate).
    raw = demo_run["raw"]
    no_estimate = raw[raw[["elastic_estimate_pa", "hertz_estimate_pa"]].isna().any(axis=1)]
    assert sorted(s["sample_id"] for s in report["skipped"]) == sorted(no_estimate["sample_id"])
    # The command's predictions are the run's own (val and test rows of predictions.csv).
    by_id = {p["sample_id"]: p["pred_pa"] for p in report["predictions"]}
    stored = demo_run["predictions"]
    assert np.allclose([by_id[i] for i in stored["sample_id"]], stored["pred_pa"], rtol=1e-4)
    exported = runner.invoke(app, ["export", run_dir, "--onnx", str(tmp_path / "m.onnx")])
    assert exported.exit_code == 0, exported.output
    # The exported graph predicts what the run predicted (onnxruntime, a separate engine).
    from tactile_compliance.inference.onnx import OnnxEstimator

    rows = stored.head(6)
    raw = raw.set_index("sample_id").loc[rows["sample_id"]]
    onnx_prediction = OnnxEstimator(tmp_path / "m.onnx").predict(
        GraspStore.open(store).read_samples(rows["sample_id"].to_numpy()),
        force=raw[[f"force_n_{i}" for i in range(3)]].to_numpy(float),
        width=raw[[f"width_m_{i}" for i in range(3)]].to_numpy(float),
        estimates=raw[["elastic_estimate_pa", "hertz_estimate_pa"]].to_numpy(float),
    )
    assert np.allclose(onnx_prediction.modulus_pa, rows["pred_pa"], rtol=1e-3)
    # The grid command: an already-complete cell is skipped, not retrained.
    again = runner.invoke(
        app,
        [
            "experiment",
            "table1",
            "--quick",
            "--seeds",
            "1",
            "--store",
            str(store),
            "--where",
            "model.name=top10nn",
            "--where",
            "inputs=ALL",
            "--where",
            "split.condition=seen",
            "--where",
            "split.grouping=grasp",
            "--set",
            "training.max_epochs=1",
            "--out",
            str(out / "runs"),
            "--results",
            str(out / "results"),
            "--json",
        ],
    )
    assert again.exit_code == 0, again.output
    summary = json.loads(again.stdout)
    assert (summary["cells"], summary["skipped"], summary["completed"]) == (1, 1, 0)
    assert summary["summary"][0]["model"] == "top10nn", summary
    grid = [
        "experiment",
        "table1",
        "--quick",
        "--seeds",
        "1",
        "--store",
        str(store),
        "--where",
        "model.name=top10nn",
        "--where",
        "split.condition=seen",
        "--where",
        "split.grouping=grasp",
        "--set",
        "training.max_epochs=1",
        "--out",
        str(out / "runs"),
        "--results",
        str(out / "results"),
    ]
    planned = runner.invoke(app, [*grid, "--dry-run"])
    assert planned.exit_code == 0, planned.output
    assert planned.output.count("complete") == 1 and planned.output.count("todo") == 3
    planned = runner.invoke(app, [*grid, "--dry-run", "--json"])
    assert planned.exit_code == 0, planned.output
    cells = json.loads(planned.stdout)["cells"]
    assert sorted(c["status"] for c in cells) == ["complete", "todo", "todo", "todo"], cells
    assert len(ResultsStore(out / "results")) == 1  # a dry run trains nothing
    # A cell that fails at run time (Top10NN cannot take 8x8 frames) is recorded, and
    # the command says so with exit status 1.
    failing_grid = [*grid, "--where", "inputs=Image", "--set", "data.image_size=[8,8]"]
    failing = runner.invoke(app, failing_grid)
    assert failing.exit_code == 1, failing.output
    assert "1 failed" in failing.output and "cell(s) failed" in failing.output
    # Re-run: the failed cell is retried (one more attempt, recorded again), the complete
    # one is not touched (its row stays byte for byte); --no-retry-failed skips it.
    before = {row["key"]: row for row in ResultsStore(out / "results").rows()}
    retried = runner.invoke(app, [*failing_grid, "--json"])
    assert retried.exit_code == 1, retried.output
    summary = json.loads(retried.stdout)
    assert (summary["cells"], summary["skipped"], summary["failed"]) == (1, 0, 1), summary
    after = {row["key"]: row for row in ResultsStore(out / "results").rows()}
    (failed_key,) = [k for k, row in after.items() if row["status"] == "failed"]
    assert after[failed_key]["attempts"] == before[failed_key]["attempts"] + 1
    assert {k: r for k, r in after.items() if k != failed_key} == {
        k: r for k, r in before.items() if k != failed_key
    }
    skipping = runner.invoke(app, [*failing_grid, "--no-retry-failed", "--json"])
    assert skipping.exit_code == 0, skipping.output
    assert json.loads(skipping.stdout)["skipped"] == 1
    assert ResultsStore(out / "results").get(failed_key) == after[failed_key]
    bad = runner.invoke(app, ["experiment", "no-such-preset"])
    assert bad.exit_code == 2 and "error" in bad.output
