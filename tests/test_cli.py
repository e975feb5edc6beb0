"""The command line: help texts, import + info round trip, clear errors."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from burgess_tree import write_tree
from tactile_compliance.cli import app

runner = CliRunner()


def test_help_lists_commands():
    result = runner.invoke(app, ["--help"])
    assert result.exit_code == 0
    for command in ("info", "import"):
        assert command in result.output
    result = runner.invoke(app, ["import", "--help"])
    assert "burgess" in result.output and "yuan" in result.output


def test_import_then_info(tmp_path):
    write_tree(tmp_path / "src")
    result = runner.invoke(
        app,
        [
            "import",
            "burgess",
            str(tmp_path / "src"),
            "--out",
            str(tmp_path / "store"),
            "--fingers",
            "markerless",
            "--size",
            "6x8",
            "--report",
            str(tmp_path / "r.json"),
        ],
    )
    assert result.exit_code == 0, result.output
    assert "Imported 12 samples" in result.output
    assert json.loads((tmp_path / "r.json").read_text())["samples_imported"] == 12
    result = runner.invoke(app, ["info", str(tmp_path / "store"), "--json"])
    assert result.exit_code == 0
    info = json.loads(result.output)
    assert info["num_samples"] == 12 and info["image_size"] == [6, 8]
    assert info["materials"] == {"Foam": 4, "Rubber": 4, "Metal": 4}
    result = runner.invoke(app, ["info", str(tmp_path / "store")])
    assert "Modulus     2e+04 .. 2e+11 Pa" in result.output


def test_errors_are_clear(tmp_path):
    write_tree(tmp_path / "src")
    args = ["import", "burgess", str(tmp_path / "src"), "--out", str(tmp_path / "store")]
    assert runner.invoke(app, args).exit_code == 0
    again = runner.invoke(app, args)
    assert again.exit_code == 2 and "--overwrite" in again.output
    bad_size = runner.invoke(app, [*args, "--overwrite", "--size", "big"])
    assert bad_size.exit_code != 0 and "HxW" in bad_size.output
    missing = runner.invoke(app, ["info", str(tmp_path / "nothing")])
    assert missing.exit_code == 2 and "no such store" in missing.output


def test_simulate_then_import(tmp_path):
    raw = tmp_path / "raw"
    result = runner.invoke(
        app,
        [
            "simulate",
            "--out",
            str(raw),
            "--objects",
            "3",
            "--grasps-per-object",
            "1",
            "--size",
            "40x56",
            "--workers",
            "1",
        ],
    )
    assert result.exit_code == 0, result.output
    assert "import burgess" in result.output
    result = runner.invoke(app, ["import", "burgess", str(raw), "--out", str(tmp_path / "s")])
    assert result.exit_code == 0, result.output
    info = json.loads(runner.invoke(app, ["info", str(tmp_path / "s"), "--json"]).output)
    assert info["source"] == "synthetic" and info["num_objects"] == 3
    assert info["image_size"] == [40, 56]
    videos = runner.invoke(
        app,
        [
            "simulate",
            "--kind",
            "shore-videos",
            "--out",
            str(tmp_path / "v"),
            "--objects",
            "2",
            "--grasps-per-object",
            "1",
            "--size",
            "40x56",
        ],
    )
    assert videos.exit_code == 0, videos.output
    assert len(list((tmp_path / "v").glob("*.avi"))) == 2
    bad = runner.invoke(app, ["simulate", "--out", str(raw), "--kind", "lidar"])
    assert bad.exit_code == 2 and "'lidar' is not one of 'gelsight', 'shore-videos'" in bad.output


def test_search_commands_pass_their_options_and_fail_in_one_line(tmp_path):
    # tune and tune-balance hand their options to training.hpo by name: a renamed option
    # or keyword would raise TypeError here instead of the store error.
    missing = str(tmp_path / "no-store")
    for args in (
        ["tune", "top10nn", "--store", missing, "--trials", "2"],
        ["tune-balance", "--store", missing, "--models", "top10nn,res_tf", "--epochs", "1"],
    ):
        result = runner.invoke(app, args)
        assert result.exit_code == 2, result.output
        assert result.output.strip().splitlines() == [
            f"error: store not found: {missing}; pass --store PATH"
        ]


def _one_error_line(result) -> str:  # type: ignore[no-untyped-def]
    """The single ``error: ...`` line of a failed command (no traceback)."""
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    lines = [line for line in result.output.strip().splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), result.output
    return lines[0]


def test_expected_errors_are_one_line_with_exit_code_2(tmp_path):
    from toy_store import make_toy_store

    store = tmp_path / "store"
    make_toy_store(store, n_objects=4, grasps=2, size=(8, 8))
    broken = tmp_path / "broken"
    broken.mkdir()
    for name in ("header.json", "samples.parquet"):  # an empty samples.parquet
        source = store / name
        if source.exists():
            (broken / name).write_bytes(b"" if name == "samples.parquet" else source.read_bytes())
    nothing = tmp_path / "nothing"
    # A checkpoint whose weights belong to another architecture (a hand-edited file).
    import torch

    from tactile_compliance.data.normalisation import NormalisationConstants
    from tactile_compliance.models import create_model
    from tactile_compliance.runs.checkpoint import save_checkpoint
    from tactile_compliance.runs.run_inputs import RunInputs

    foreign = tmp_path / "foreign.pt"
    model = create_model("top10nn", inputs="ALL")
    save_checkpoint(
        foreign,
        model,
        run_inputs=RunInputs((8, 8), (8, 8), NormalisationConstants(), model.inputs),
        config={},
        seed=0,
    )
    payload = torch.load(foreign, weights_only=True)
    payload["hparams"] = {**payload["hparams"], "decoder_sizes": [7]}
    torch.save(payload, foreign)
    cases = {
        "no store (split)": ["split", str(nothing), "--out", str(tmp_path / "s.json")],
        "no store (train)": [
            "train",
            "--set",
            f"data.store={nothing}",
            "--set",
            f"output_dir={tmp_path / 'runs'}",
        ],
        "empty samples.parquet": ["info", str(broken)],
        "no run (evaluate)": ["evaluate", str(nothing)],
        "bad config key": [
            "train",
            "--set",
            f"data.store={store}",
            "--set",
            f"output_dir={tmp_path / 'runs'}",
            "--set",
            "training.lrr=1",
        ],
        "another model's weights": ["predict", str(foreign), str(store)],
    }
    if not torch.cuda.is_available():
        cases["no GPU"] = [
            "train",
            "--set",
            f"data.store={store}",
            "--set",
            f"output_dir={tmp_path / 'runs'}",
            "--set",
            "training.device=cuda",
        ]
    for label, args in cases.items():
        result = runner.invoke(app, args)
        assert result.exit_code == 2, (label, result.output, result.exception)
        _one_error_line(result)
    assert not list(tmp_path.glob("runs")), "a failed check writes no run directory"


def test_debug_shows_the_traceback(tmp_path):
    args = ["split", str(tmp_path / "nothing"), "--out", str(tmp_path / "s.json")]
    assert runner.invoke(app, args).exit_code == 2
    result = runner.invoke(app, ["--debug", *args])
    assert result.exit_code != 0 and result.exception is not None
    assert not isinstance(result.exception, SystemExit)


def test_split_summary_takes_the_split_and_the_store_in_either_order(tmp_path):
    from toy_store import make_toy_store

    store = tmp_path / "store"
    make_toy_store(store, n_objects=6, grasps=2, size=(8, 8))
    split = tmp_path / "split.json"
    assert runner.invoke(app, ["split", str(store), "--out", str(split)]).exit_code == 0
    given = runner.invoke(app, ["split-summary", str(split), str(store), "--json"])
    swapped = runner.invoke(app, ["split-summary", str(store), str(split), "--json"])
    assert given.exit_code == 0 and swapped.exit_code == 0, swapped.output
    assert json.loads(swapped.output) == json.loads(given.output)


def test_split_json_holds_the_filter_report_and_the_split(tmp_path):
    from toy_store import make_toy_store

    store = tmp_path / "store"
    make_toy_store(store, n_objects=6, grasps=2, size=(8, 8))
    split = tmp_path / "split.json"
    result = runner.invoke(app, ["split", str(store), "--out", str(split), "--json"])
    assert result.exit_code == 0, result.output
    payload = json.loads(result.output)
    assert payload["out"] == str(split) and split.is_file()
    assert payload["split"] == json.loads(
        runner.invoke(app, ["split-summary", str(split), str(store), "--json"]).output
    )
    assert payload["filter"]["rules"]


def test_simulate_and_import_print_their_reports_as_json(tmp_path):
    raw = tmp_path / "raw"
    args = ["simulate", "--out", str(raw), "--objects", "2", "--grasps-per-object", "1"]
    simulated = runner.invoke(app, [*args, "--size", "40x56", "--workers", "1", "--json"])
    assert simulated.exit_code == 0, simulated.output
    assert json.loads(simulated.stdout)["objects_total"] == 2  # progress goes to stderr
    imported = runner.invoke(
        app,
        [
            *("import", "burgess", str(raw), "--out", str(tmp_path / "s"), "--json"),
            *("--report", str(tmp_path / "r.json")),
        ],
    )
    assert imported.exit_code == 0, imported.output
    assert json.loads(imported.stdout) == json.loads((tmp_path / "r.json").read_text())
