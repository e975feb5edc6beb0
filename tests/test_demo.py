"""The one-command demo, end to end in its reduced CI mode."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from tactile_compliance.cli import app
from tactile_compliance.data.store import GraspStore
from tactile_compliance.runs.results import ResultsStore


def test_demo_ci_mode_runs_every_layer(tmp_path):
    out = tmp_path / "demo"
    result = CliRunner().invoke(app, ["demo", "--out", str(out), "--mode", "ci"])
    assert result.exit_code == 0, result.output
    assert "Demo finished" in result.output
    store = GraspStore.open(out / "stores" / "gelsight")
    assert store.header.source == "synthetic" and len(store) > 0
    assert GraspStore.open(out / "stores" / "shore").header.source == "yuan"
    rows = ResultsStore(out / "results").table()
    assert len(rows) >= 1 and (rows["status"] == "complete").all()
    report = (out / "report" / "report.html").read_text()
    assert "Table I" in report and "data:image/png;base64" in report
    summary = json.loads((out / "report" / "report.json").read_text())
    assert summary  # the machine-readable report exists
    # Re-running continues: nothing is retrained, the same rows stay.
    again = CliRunner().invoke(app, ["demo", "--out", str(out), "--mode", "ci"])
    assert again.exit_code == 0, again.output
    assert len(ResultsStore(out / "results")) == len(rows)


def test_cli_predict_export_and_experiment_on_the_demo_output(tmp_path):
    out = tmp_path / "demo"
    runner = CliRunner()
    assert runner.invoke(app, ["demo", "--out", str(out), "--mode", "ci"]).exit_code == 0
    run_dir = ResultsStore(out / "results").table()["run_dir"].iloc[0]
    store = out / "stores" / "gelsight"
    predicted = runner.invoke(app, ["predict", run_dir, str(store), "--json"])
    assert predicted.exit_code == 0, predicted.output
    report = json.loads(predicted.output)
    assert report["summary"]["n_predicted"] > 0
    assert all(p["pred_pa"] > 0 for p in report["predictions"])
    exported = runner.invoke(app, ["export", run_dir, "--onnx", str(tmp_path / "m.onnx")])
    assert exported.exit_code == 0, exported.output
    assert (tmp_path / "m.onnx").stat().st_size > 0
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
            "--set",
            "training.max_epochs=1",
            "--output-dir",
            str(out / "runs"),
            "--results",
            str(out / "results"),
        ],
    )
    assert again.exit_code == 0, again.output
    assert "1 already complete" in again.output
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
        "--set",
        "training.max_epochs=1",
        "--output-dir",
        str(out / "runs"),
        "--results",
        str(out / "results"),
    ]
    planned = runner.invoke(app, [*grid, "--dry-run"])
    assert planned.exit_code == 0, planned.output
    assert planned.output.count("complete") == 1 and planned.output.count("todo") == 3
    assert len(ResultsStore(out / "results")) == 1  # a dry run trains nothing
    # A cell that fails at run time (Top10NN cannot take 8x8 frames) is recorded, and
    # the command says so with exit status 1.
    failing = runner.invoke(
        app,
        [*grid, "--where", "inputs=Image", "--set", "data.image_size=[8,8]"],
    )
    assert failing.exit_code == 1, failing.output
    assert "1 failed" in failing.output and "cell(s) failed" in failing.output
    bad = runner.invoke(app, ["experiment", "no-such-preset"])
    assert bad.exit_code == 2 and "error" in bad.output
