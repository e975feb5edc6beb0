"""Evidence that the models learn (issue 13): three object conditions and a scalar reference.

* The paper's per-sample Seen split and the grasp-grouped Seen split are different splits
  with the documented leakage: grasps shared between train and test, or none. The leakage
  is counted here from the raw ``object`` / ``grasp`` columns, not with ``data.splits``.
* The scalar reference (gradient-boosted trees on F, W, log10 E) is fitted on the training
  rows only, depends on the strategy's scalar inputs, beats the median where the scalars
  carry the label, and does not exist for Image.
* A real tiny grid of the ``table1`` preset (all three object conditions) is run, and every
  new cell of the report (the three column groups, the scalar reference rows) is checked
  against the stored runs.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from tactile_compliance.config import ConfigError, config_to_dict
from tactile_compliance.data.normalisation import NormalisationConstants, normalise_modulus
from tactile_compliance.data.store import GraspStore
from tactile_compliance.evaluation.report import build_report
from tactile_compliance.runs.metrics import compute_metrics, reference_predictions
from tactile_compliance.runs.results import ResultsStore
from tactile_compliance.training.experiment import plan_experiment, run_cell
from tactile_compliance.training.experiment_file import expand_experiment, load_experiment
from tactile_compliance.training.train import prepare_data
from toy_store import make_toy_store

#: (split.condition, split.grouping) of the three column groups, and their headers.
CONDITIONS = {
    ("seen", "per_sample"): "Seen, per-sample (paper)",
    ("seen", "grasp"): "Seen, grasp-grouped",
    ("unseen", "object"): "UnSeen",
}


@pytest.fixture(scope="module")
def toy_store(tmp_path_factory: pytest.TempPathFactory) -> GraspStore:
    # 16 objects x 4 grasps x 2 fingers: a grasp has two near-duplicate samples.
    return make_toy_store(tmp_path_factory.mktemp("evidence") / "store")


def _pairs(samples: pd.DataFrame, ids: Any) -> set[tuple[str, int]]:
    """The (object, grasp) pairs of the samples ``ids``, from the raw columns."""
    rows = samples.set_index("sample_id").loc[np.asarray(ids, dtype=np.int64)]
    return set(zip(rows["object"].astype(str), rows["grasp"].astype(int), strict=True))


def _objects(samples: pd.DataFrame, ids: Any) -> set[str]:
    return {obj for obj, _ in _pairs(samples, ids)}


# ============================================================================ the splits
def test_table1_runs_three_object_conditions_with_their_leakage(toy_store: GraspStore) -> None:
    cells = expand_experiment(
        load_experiment("table1", quick=True),
        seeds=[3],
        store=toy_store.path,
        overrides=["data.fingers=[markerless, markers]"],
        where=["model.name=top10nn", "inputs=ALL"],
    )
    by_condition = {(c.cfg.split.condition, c.cfg.split.grouping): c.cfg for c in cells}
    assert len(cells) == 3
    assert set(by_condition) == {("seen", "per_sample"), ("seen", "grasp"), ("unseen", "grasp")}
    samples = toy_store.samples
    splits = {key: prepare_data(cfg, None).split for key, cfg in by_condition.items()}
    per_sample, grasp, unseen = (
        splits[("seen", "per_sample")],
        splits[("seen", "grasp")],
        splits[("unseen", "grasp")],
    )
    # Two different splits of the same samples.
    assert set(per_sample.test_ids) != set(grasp.test_ids)
    for split in (per_sample, grasp):
        assert len(set(split.train_ids) | set(split.val_ids) | set(split.test_ids)) == len(samples)
    # The paper's per-sample split: grasps straddle train and test (the other finger of a
    # test sample is usually in training). Grasp-grouped: not one grasp is shared.
    shared = _pairs(samples, per_sample.train_ids) & _pairs(samples, per_sample.test_ids)
    assert len(shared) >= 3
    assert not _pairs(samples, grasp.train_ids) & _pairs(samples, grasp.test_ids)
    assert not _pairs(samples, grasp.train_ids) & _pairs(samples, grasp.val_ids)
    # Both seen splits still share objects between train and test; unseen shares none.
    assert _objects(samples, grasp.train_ids) & _objects(samples, grasp.test_ids)
    assert not _objects(samples, unseen.train_ids) & _objects(samples, unseen.test_ids)
    assert not _objects(samples, unseen.train_ids) & _objects(samples, unseen.val_ids)


def test_a_linked_axis_cannot_be_crossed_with_one_of_its_keys(tmp_path: Path) -> None:
    # Extending table1 with a plain split.condition axis would set the key twice.
    (tmp_path / "both.yaml").write_text("extends: table1\ngrid: {split.condition: [seen]}\n")
    with pytest.raises(ConfigError, match=r"both set 'split\.condition'"):
        expand_experiment(load_experiment(tmp_path / "both.yaml"))
    # The invalid pair stays a configuration error inside a linked axis too.
    (tmp_path / "bad.yaml").write_text(
        "description: x\n"
        "grid:\n  objects: [{split.condition: unseen, split.grouping: per_sample}]\n"
    )
    with pytest.raises(ConfigError, match="per_sample"):
        expand_experiment(load_experiment(tmp_path / "bad.yaml"))
    (tmp_path / "mixed.yaml").write_text("description: x\ngrid:\n  objects: [{seed: 1}, 3]\n")
    with pytest.raises(ConfigError, match="linked axis"):
        expand_experiment(load_experiment(tmp_path / "mixed.yaml"))


# ============================================================================ the reference
def _scalar_frame(n: int, seed: int, carrier: str = "force") -> pd.DataFrame:
    """Samples whose log10 E is a smooth function of the forces (or of the widths)."""
    rng = np.random.default_rng(seed)
    force = rng.uniform(5.0, 60.0, (n, 3))
    width = rng.uniform(0.02, 0.08, (n, 3))
    driver = force[:, 2] / 60.0 if carrier == "force" else (width[:, 0] - 0.02) / 0.06
    log_e = 3.5 + 8.0 * driver + rng.normal(0.0, 0.05, n)
    frame = pd.DataFrame(
        {
            "sample_id": np.arange(n),
            "modulus_pa": 10.0**log_e,
            **{f"force_n_{i}": force[:, i] for i in range(3)},
            **{f"width_m_{i}": width[:, i] for i in range(3)},
            "elastic_estimate_pa": 10 ** rng.uniform(3, 11, n),
            "hertz_estimate_pa": np.where(rng.random(n) < 0.2, np.nan, 10 ** rng.uniform(3, 11, n)),
        }
    )
    return frame


def test_the_scalar_reference_never_sees_test_labels() -> None:
    train, test = _scalar_frame(400, 0), _scalar_frame(120, 1)
    first = reference_predictions(train, test, inputs="ALL", seed=4)
    # Garbage in the test labels: a reference fitted on (or tuned with) them would change.
    garbage = test.assign(modulus_pa=np.random.default_rng(9).uniform(1.0, 1e15, len(test)))
    second = reference_predictions(train, garbage, inputs="ALL", seed=4)
    np.testing.assert_array_equal(first["scalar_gbr"], second["scalar_gbr"])
    np.testing.assert_array_equal(first["median"], second["median"])
    # Without any label column at all it predicts the same.
    third = reference_predictions(train, test.drop(columns="modulus_pa"), inputs="ALL", seed=4)
    np.testing.assert_array_equal(first["scalar_gbr"], third["scalar_gbr"])
    # A test row's prediction does not depend on the other test rows.
    alone = reference_predictions(train, test.iloc[[7]], inputs="ALL", seed=4)
    assert alone["scalar_gbr"][0] == first["scalar_gbr"][7]
    # The training labels are what it learns from: shuffle them and the predictions move.
    rng = np.random.default_rng(2)
    shuffled = train.assign(modulus_pa=rng.permutation(train["modulus_pa"].to_numpy()))
    moved = reference_predictions(shuffled, test, inputs="ALL", seed=4)
    assert np.max(np.abs(np.log10(moved["scalar_gbr"] / first["scalar_gbr"]))) > 0.5
    # Same inputs, same seed: the same numbers.
    again = reference_predictions(train, test, inputs="ALL", seed=4)
    np.testing.assert_array_equal(first["scalar_gbr"], again["scalar_gbr"])


@pytest.mark.parametrize("inputs", ["ImageF", "ImageFW", "ALL"])
def test_the_scalar_reference_beats_the_median_when_the_scalars_carry_the_label(
    inputs: str,
) -> None:
    train, test = _scalar_frame(500, 0), _scalar_frame(200, 1)
    c = NormalisationConstants()
    preds = reference_predictions(train, test, c, inputs=inputs, seed=0)
    scalar = compute_metrics(test["modulus_pa"], preds["scalar_gbr"], c)
    median = compute_metrics(test["modulus_pa"], preds["median"], c)
    assert scalar["nmse"] < 0.1 * median["nmse"]
    assert scalar["log10_accuracy"] > 0.95 > median["log10_accuracy"]


def test_the_scalar_reference_uses_exactly_the_strategys_scalars() -> None:
    # The label rides on the first width: only strategies that see W can learn it.
    train, test = _scalar_frame(500, 0, "width"), _scalar_frame(200, 1, "width")
    c = NormalisationConstants()

    def nmse(name: str, inputs: str) -> float:
        preds = reference_predictions(train, test, c, inputs=inputs, seed=0)
        return compute_metrics(test["modulus_pa"], preds[name], c)["nmse"]

    median = nmse("median", "ImageF")
    assert nmse("scalar_gbr", "ImageF") > 0.8 * median  # forces only: no better than median
    assert nmse("scalar_gbr", "ImageFW") < 0.1 * median
    # ALL adds log10 E; here it is noise, but NaN-bearing Hertz values must not break it.
    assert nmse("scalar_gbr", "ALL") < 0.1 * median


def test_image_has_no_scalar_reference() -> None:
    train, test = _scalar_frame(50, 0), _scalar_frame(10, 1)
    assert set(reference_predictions(train, test, inputs="Image")) == {"median", "analytical"}
    # Called as before (no strategy): the two strategy-free references only.
    assert set(reference_predictions(train, test)) == {"median", "analytical"}


# ============================================================================ a real grid
@pytest.fixture(scope="module")
def grid(toy_store: GraspStore, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """The table1 preset's quick cells for Res-Tf x {Image, ALL}, 2 seeds, 1 short epoch.

    Res-Tf because the quick preset freezes its backbone: the features are computed once and
    every cell trains a small head in a few seconds (Top10NN trains its CNN, 3x slower).

    Each cell goes through ``run_cell``, the grid's own task (train, then record the row),
    in this process: the Dask path itself is tested in test_experiment.py.
    """
    root = tmp_path_factory.mktemp("grid")
    plan = plan_experiment(
        "table1",
        quick=True,
        seeds=2,
        store=toy_store.path,
        where=["model.name=res_tf", "inputs=[Image, ALL]"],
        overrides=[
            "data.fingers=[markerless, markers]",  # two samples per grasp
            "training.max_epochs=1",
            "training.limit_batches=2",
        ],
        output_dir=root / "runs",
        results=root / "results",
    )
    assert len(plan.cells) == 2 * 3 * 2  # inputs x object conditions x seeds
    for cell in plan.cells:
        row = run_cell(
            config_to_dict(cell.cfg),
            cell.key,
            plan.preset,
            str(plan.results_path),
            keep_checkpoints="none",
        )
        assert row["status"] == "complete", row.get("error")
    report = build_report(plan.results_path, root / "report", formats=("md",), strict=True)
    rows = ResultsStore(plan.results_path).rows()
    return {"rows": rows, "report": report, "samples": toy_store.samples}


def _fmt(values: list[float]) -> str:
    arr = np.asarray(values, dtype=float)
    return f"{arr.mean():.4f} ± {arr.std(ddof=1):.4f}"


def _md_table(markdown: str, title_start: str) -> tuple[list[str], list[list[str]]]:
    """Header and body rows (cell lists) of the first Markdown table after ``title_start``."""
    lines = markdown[markdown.index(title_start) :].splitlines()
    table: list[list[str]] = []
    for line in lines[1:]:
        if line.startswith("|"):
            table.append(
                [c.strip().replace("**", "") for c in line.strip().strip("|").split(" | ")]
            )
        elif table:
            break
    return table[0], table[2:]


def test_grid_runs_keep_their_splits_leakage(grid: dict[str, Any]) -> None:
    samples = grid["samples"]
    seen_shared = {}
    for row in grid["rows"]:
        split = json.loads((Path(row["run_dir"]) / "split.json").read_text())
        train, test = split["train_ids"], split["test_ids"]
        shared_grasps = _pairs(samples, train) & _pairs(samples, test)
        shared_objects = _objects(samples, train) & _objects(samples, test)
        key = (row["condition"], row["grouping"])
        if key == ("seen", "per_sample"):
            assert shared_grasps, row["run_name"]
        elif key == ("seen", "grasp"):
            assert not shared_grasps and shared_objects, row["run_name"]
        else:
            assert key == ("unseen", "object") and not shared_objects, row["run_name"]
        seen_shared[key] = True
    assert set(seen_shared) == set(CONDITIONS)


def test_every_new_report_cell_matches_the_stored_runs(grid: dict[str, Any]) -> None:
    rows, report = grid["rows"], grid["report"]
    header, body = _md_table(report.documents["md"].read_text(), "**Table I — preset table1")
    groups = list(CONDITIONS.items())
    for index, (_, label) in enumerate(groups):
        # Markdown folds the group header into each column: "Seen, grasp-grouped N-MSE".
        assert header[2 + 2 * index] == f"{label} log₁₀ accuracy"
        assert header[3 + 2 * index] == f"{label} N-MSE"
    by_line = {(line[0], line[1]): line for line in body}
    cells = report.tables["tableI"]
    checked = 0
    for (condition, grouping), _ in groups:
        column0 = 2 + 2 * [key for key, _ in groups].index((condition, grouping))
        for inputs in ("Image", "ALL"):
            runs = [
                r
                for r in rows
                if (r["condition"], r["grouping"], r["inputs"]) == (condition, grouping, inputs)
            ]
            assert sorted(r["seed"] for r in runs) == [0, 1]
            for offset, metric in enumerate(("log10_accuracy", "nmse")):
                # The model row: mean ± std over the two seeds of the recorded metric ...
                values = [r[f"test_{metric}"] for r in runs]
                assert by_line[("Res-Tf", inputs)][column0 + offset] == _fmt(values)
                got = cells[
                    (cells["model"] == "res_tf")
                    & (cells["inputs"] == inputs)
                    & (cells["condition"] == condition)
                    & (cells["grouping"] == grouping)
                    & (cells["metric"] == metric)
                ]
                assert len(got) == 1 and got["mean"].iloc[0] == pytest.approx(np.mean(values))
                # ... and the scalar reference row of this strategy (none for Image).
                line = by_line[("Scalar GBR (reference)", inputs)]
                if inputs == "Image":
                    assert line[column0 + offset] == "–"
                    assert all(f"ref_scalar_gbr_{metric}" not in r for r in runs)
                else:
                    ref = [
                        r[f"ref_scalar_gbr_{metric}"] for r in sorted(runs, key=lambda r: r["seed"])
                    ]
                    assert line[column0 + offset] == _fmt(ref)
                checked += 1
    assert checked == 3 * 2 * 2
    assert [line[0] for line in body[-4:]] == [
        "Median (reference)",
        "Analytical (reference)",
        "Scalar GBR (reference)",
        "Scalar GBR (reference)",
    ]


def test_recorded_metrics_are_recomputed_from_the_runs_files(grid: dict[str, Any]) -> None:
    """The rows the table reads agree with each run's predictions and its own split."""
    samples = grid["samples"].set_index("sample_id")
    c = NormalisationConstants()
    for row in grid["rows"]:
        run_dir = Path(row["run_dir"])
        predictions = pd.read_csv(run_dir / "predictions.csv")
        test = predictions[predictions["split"] == "test"]
        y, y_hat = normalise_modulus(test["modulus_pa"], c), normalise_modulus(test["pred_pa"], c)
        assert row["test_nmse"] == pytest.approx(float(np.mean((y_hat - y) ** 2)))
        # The scalar reference of the row is the one fitted on the run's own training rows.
        split = json.loads((run_dir / "split.json").read_text())
        train_rows = samples.loc[split["train_ids"]].reset_index()
        test_rows = samples.loc[split["test_ids"]].reset_index()
        preds = reference_predictions(
            train_rows, test_rows, c, inputs=row["inputs"], seed=row["seed"]
        )
        for name, values in preds.items():
            expected = compute_metrics(test_rows["modulus_pa"], values, c)
            assert row[f"ref_{name}_nmse"] == pytest.approx(expected["nmse"], rel=1e-9)
        assert ("scalar_gbr" in preds) == (row["inputs"] != "Image")
