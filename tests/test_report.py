"""The report layer: every table cell against the stored runs, every figure produced.

A fake results store is filled with ``ResultsStore.record`` rows (random metrics) and fake
run directories (predictions.csv, groups.csv, logs/metrics.csv, config.yaml) over a toy
GraspStore. Expected means and standard deviations are computed here, independently of
``tables.py`` (numpy, straight from the rows this test wrote), and compared with the
returned DataFrames *and* with the cells of the Markdown report.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from tactile_compliance import __version__
from tactile_compliance.data.normalisation import NormalisationConstants, normalise_modulus
from tactile_compliance.data.store_writer import GraspStoreWriter
from tactile_compliance.evaluation.report import build_report
from tactile_compliance.runs.results import ResultsStore
from toy_store import make_toy_store

MODELS = ("top10nn", "vgg_lstm", "res_tf")
LABELS = {"top10nn": "Top10NN", "vgg_lstm": "VGG-LSTM", "res_tf": "Res-Tf"}
INPUTS = ("Image", "ImageF", "ImageFW", "ALL")
SEEDS = (0, 1, 2)
#: Table I cell left out on purpose: the report must print "–" there.
MISSING = ("res_tf", "ImageF", "unseen")
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


# ============================================================================ fake store
def _fmt(mean: float, std: float, digits: int = 4) -> str:
    return f"{mean:.{digits}f} ± {std:.{digits}f}"


def _mean_std(values: list[float]) -> tuple[float, float]:
    arr = np.asarray(values, dtype=float)
    return float(arr.mean()), float(arr.std(ddof=1))


def _make_shore_store(path: Path) -> Path:
    """A 12-sample store whose header says source "yuan" (Table III by header, not preset)."""
    rng = np.random.default_rng(5)
    with GraspStoreWriter(path, (8, 8), "yuan") as writer:
        for index in range(12):
            writer.append(
                rng.uniform(0.4, 0.6, (3, 8, 8, 3)).astype(np.float32),
                {
                    "object": f"shore_{index}",
                    "grasp": 0,
                    "finger": "markerless",
                    "material": "Silicone" if index % 2 else "Foam",
                    "shape": "Cylinder",
                    "modulus_pa": 10 ** (4 + 2.5 * index / 11),
                },
            )
    return path


def _write_run_dir(
    run_dir: Path,
    samples: pd.DataFrame,
    rng: np.random.Generator,
    noise_decades: float,
    label_range: tuple[float, float] = (1e3, 1e12),
) -> dict[str, float]:
    """predictions.csv / groups.csv / logs/metrics.csv / config.yaml; returns test metrics."""
    run_dir.mkdir(parents=True)
    test = samples.sample(n=min(40, len(samples)), random_state=int(rng.integers(1 << 30)))
    test = test.reset_index(drop=True)
    pred = test["modulus_pa"].to_numpy() * 10 ** rng.normal(0, noise_decades, len(test))
    predictions = test[
        [
            "sample_id",
            "object",
            "grasp",
            "augmentation",
            "finger",
            "material",
            "shape",
            "modulus_pa",
        ]
    ].assign(pred_pa=pred, split="test")
    val = predictions.head(5).assign(split="val", pred_pa=predictions["modulus_pa"].head(5))
    pd.concat([predictions, val]).to_csv(run_dir / "predictions.csv", index=False)
    c = NormalisationConstants.from_label_range(label_range)
    err2 = (normalise_modulus(pred, c) - normalise_modulus(test["modulus_pa"].to_numpy(), c)) ** 2
    d = np.abs(np.log10(pred) - np.log10(test["modulus_pa"].to_numpy()))
    nmse = float(err2.mean())
    # groups.csv as train() writes it, but with made-up per-group numbers (the report must
    # only aggregate them, not recompute them).
    groups = [
        {
            "grouping": "all",
            "group": "all",
            "n": len(test),
            "nmse": nmse,
            "log10_accuracy": float(np.mean(d <= 1)),
        }
    ]
    soft = np.where(test["modulus_pa"] < 2.75e5, "soft", "hard")
    for grouping, keys in (
        ("material", test["material"]),
        ("shape", test["shape"]),
        ("soft_hard", pd.Series(soft)),
    ):
        for group in sorted(set(keys)):
            groups.append(
                {
                    "grouping": grouping,
                    "group": group,
                    "n": int((keys == group).sum()),
                    "nmse": float(rng.uniform(0.001, 0.05)),
                    "log10_accuracy": float(rng.uniform(0.3, 1.0)),
                }
            )
    pd.DataFrame(groups).to_csv(run_dir / "groups.csv", index=False)
    (run_dir / "logs").mkdir()
    epochs = int(rng.integers(5, 9))  # early stopping: runs differ in length
    scale = float(rng.uniform(0.5, 2.0))
    log_rows = []
    for epoch in range(epochs):  # Lightning: train and val values on separate lines
        log_rows.append(
            {
                "epoch": epoch,
                "step": epoch,
                "train_loss": scale * 0.1 / (epoch + 1),
                "val_nmse": np.nan,
            }
        )
        log_rows.append(
            {
                "epoch": epoch,
                "step": epoch,
                "train_loss": np.nan,
                "val_nmse": scale * 0.05 / (epoch + 1) + 0.01,
            }
        )
    pd.DataFrame(log_rows).to_csv(run_dir / "logs" / "metrics.csv", index=False)
    (run_dir / "config.yaml").write_text(
        f"data:\n  label_range_pa: [{label_range[0]:.1e}, {label_range[1]:.1e}]\n"
    )
    return {"nmse": nmse, "log10_accuracy": float(np.mean(d <= 1)), "r2": float(rng.uniform(0, 1))}


class FakeResults:
    """Builds the fake results store and remembers what it recorded."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.results = ResultsStore(root / "results")
        self.rows: list[dict[str, Any]] = []
        self.rng = np.random.default_rng(0)
        self.store = make_toy_store(root / "toy_store", n_objects=12, grasps=2)
        self.shore_store = _make_shore_store(root / "shore_store")
        self.samples = self.store.samples
        self.shore_samples = pd.read_parquet(self.shore_store / "samples.parquet")
        self.count = 0

    def record(self, **row: Any) -> dict[str, Any]:
        self.count += 1
        base: dict[str, Any] = {
            "key": f"k{self.count:04d}",
            "run_name": f"run{self.count:04d}",
            "store": str(self.store.path),
            "subset": None,
            "t_balance": None,
            "status": "complete",
            "error": None,
            "attempts": 1,
            "backbone_weights": "none",
            "freeze_backbone": True,
            "image_size": [32, 32],
        }
        base.update(row)
        self.results.record(base)
        self.rows.append(base)
        return base

    def metrics(self, **extra: float) -> dict[str, float]:
        rng = self.rng
        return {
            "test_log10_accuracy": float(rng.uniform(0.3, 0.95)),
            "test_nmse": float(rng.uniform(0.005, 0.05)),
            "test_r2": float(rng.uniform(0.2, 0.95)),
            **extra,
        }


@pytest.fixture(scope="module")
def fake(tmp_path_factory: pytest.TempPathFactory) -> FakeResults:
    fake = FakeResults(tmp_path_factory.mktemp("report"))
    rng = fake.rng
    # ---- Table I (random): full grid minus one cell; references differ per seed only.
    ref = {
        (cond, seed, name, metric): float(rng.uniform(0.01, 0.6))
        for cond in ("seen", "unseen")
        for seed in SEEDS
        for name in ("median", "analytical")
        for metric in ("log10_accuracy", "nmse")
    }
    for model in MODELS:
        for inputs in INPUTS:
            for condition in ("seen", "unseen"):
                if (model, inputs, condition) == MISSING:
                    continue
                for seed in SEEDS:
                    refs = {
                        f"ref_{n}_{m}": ref[(condition, seed, n, m)]
                        for n in ("median", "analytical")
                        for m in ("log10_accuracy", "nmse")
                    }
                    fake.record(
                        preset="table1",
                        model=model,
                        inputs=inputs,
                        condition=condition,
                        sampling="random",
                        seed=seed,
                        run_dir=None,
                        **fake.metrics(**refs),
                    )
    # A failed row that carries (bogus) metrics: it must not count anywhere.
    fake.record(
        preset="table1",
        model="top10nn",
        inputs="Image",
        condition="seen",
        sampling="random",
        seed=7,
        status="failed",
        run_dir=None,
        error="Traceback ...\nRuntimeError: CUDA out of memory (fake)",
        test_log10_accuracy=99.0,
        test_nmse=99.0,
    )
    # ---- Table II (balanced): Image and ALL, seen, with run directories (Fig. 5, extras).
    for model in MODELS:
        for inputs in ("Image", "ALL"):
            for seed in SEEDS:
                run_dir = fake.root / "runs" / f"t2-{model}-{inputs}-{seed}"
                m = _write_run_dir(run_dir, fake.samples, rng, noise_decades=0.3 + 0.2 * seed)
                fake.record(
                    preset="table2",
                    model=model,
                    inputs=inputs,
                    condition="seen",
                    sampling="balanced",
                    seed=seed,
                    t_balance=0.5,
                    # Relative, as grids write it ("runs/NAME" from their working dir).
                    run_dir=f"runs/{run_dir.name}",
                    test_log10_accuracy=m["log10_accuracy"],
                    test_nmse=m["nmse"],
                    test_r2=m["r2"],
                )
    # ---- Fig. 6 (rolling windows) and Fig. 7 (shapes).
    for model in ("vgg_lstm", "res_tf"):
        for window in range(7):
            for seed in SEEDS:
                fake.record(
                    preset="rolling-window",
                    model=model,
                    inputs="Image",
                    condition="seen",
                    sampling="random",
                    seed=seed,
                    subset=window,
                    run_dir=None,
                    **fake.metrics(),
                )
        for inputs in ("Image", "ALL"):
            for shape in ("Sphere", "Cylinder"):
                for seed in SEEDS:
                    fake.record(
                        preset="shape-test",
                        model=model,
                        inputs=inputs,
                        condition="seen",
                        sampling="random",
                        seed=seed,
                        subset=shape,
                        run_dir=None,
                        **fake.metrics(),
                    )
    # ---- Soft / hard subsets.
    for subset in ("soft", "hard"):
        for seed in SEEDS:
            fake.record(
                preset="softhard",
                model="vgg_lstm",
                inputs="Image",
                condition="seen",
                sampling="random",
                seed=seed,
                subset=subset,
                run_dir=None,
                **fake.metrics(),
            )
    # ---- Table III: a store whose header says "yuan" (preset name deliberately neutral).
    for model in MODELS:
        for seed in SEEDS:
            run_dir = fake.root / "runs" / f"shore-{model}-{seed}"
            m = _write_run_dir(run_dir, fake.shore_samples, rng, 0.2, label_range=(1e3, 1e7))
            fake.record(
                preset="shore",
                store=str(fake.shore_store),
                model=model,
                inputs="Image",
                condition="seen",
                sampling="random",
                seed=seed,
                run_dir=str(run_dir),
                test_log10_accuracy=m["log10_accuracy"],
                test_nmse=m["nmse"],
                test_r2=m["r2"],
            )
    return fake


@pytest.fixture(scope="module")
def report(fake: FakeResults, tmp_path_factory: pytest.TempPathFactory) -> Any:
    out = tmp_path_factory.mktemp("out")
    return build_report(fake.results.path, out, formats=("md", "html", "tex"), strict=True)


def _rows(fake: FakeResults, **where: Any) -> list[dict[str, Any]]:
    return [
        r
        for r in fake.rows
        if r["status"] == "complete" and all(r.get(k) == v for k, v in where.items())
    ]


def _md_section(markdown: str, title_start: str) -> list[list[str]]:
    """The body rows (as cell lists) of the first Markdown table after ``title_start``."""
    start = markdown.index(title_start)
    lines = markdown[start:].splitlines()
    table: list[list[str]] = []
    in_table = False
    for line in lines[1:]:
        if line.startswith("|"):
            in_table = True
            table.append([c.strip() for c in line.strip().strip("|").split(" | ")])
        elif in_table:
            break
    return table[2:]  # drop the header and the --- line


def _unbold(text: str) -> str:
    return text.replace("**", "")


# ============================================================================ Table I / II
def test_table1_every_cell_matches_the_runs(fake: FakeResults, report: Any) -> None:
    cells = report.tables["tableI"]
    markdown = report.documents["md"].read_text()
    body = _md_section(markdown, "**Table I — preset table1.**")
    assert len(body) == len(MODELS) * len(INPUTS) + 2  # + median and analytical references
    checked = 0
    for row_index, (model, inputs) in enumerate((m, i) for m in MODELS for i in INPUTS):
        md_row = body[row_index]
        assert md_row[:2] == [LABELS[model], inputs]
        for c_index, condition in enumerate(("seen", "unseen")):
            for m_index, metric in enumerate(("log10_accuracy", "nmse")):
                column = 2 + 2 * c_index + m_index
                if (model, inputs, condition) == MISSING:
                    assert md_row[column] == "–"
                    continue
                runs = _rows(
                    fake,
                    preset="table1",
                    model=model,
                    inputs=inputs,
                    condition=condition,
                    sampling="random",
                )
                assert sorted(r["seed"] for r in runs) == list(SEEDS)
                mean, std = _mean_std([r[f"test_{metric}"] for r in runs])
                got = cells[
                    (cells["model"] == model)
                    & (cells["inputs"] == inputs)
                    & (cells["condition"] == condition)
                    & (cells["metric"] == metric)
                ]
                assert len(got) == 1
                assert got["mean"].iloc[0] == pytest.approx(mean, rel=1e-12)
                assert got["std"].iloc[0] == pytest.approx(std, rel=1e-12)
                assert got["n"].iloc[0] == len(SEEDS)
                assert _unbold(md_row[column]) == _fmt(mean, std)
                checked += 1
    assert checked == (len(MODELS) * len(INPUTS) * 2 - 1) * 2


def test_table1_bold_marks_the_best_model_per_column(fake: FakeResults, report: Any) -> None:
    body = _md_section(report.documents["md"].read_text(), "**Table I — preset table1.**")
    keys = [(m, i) for m in MODELS for i in INPUTS]
    for c_index, condition in enumerate(("seen", "unseen")):
        for m_index, metric in enumerate(("log10_accuracy", "nmse")):
            column = 2 + 2 * c_index + m_index
            means = {}
            for model, inputs in keys:
                runs = _rows(
                    fake,
                    preset="table1",
                    model=model,
                    inputs=inputs,
                    condition=condition,
                    sampling="random",
                )
                if runs:
                    means[(model, inputs)] = np.mean([r[f"test_{metric}"] for r in runs])
            pick = max if metric == "log10_accuracy" else min
            best = pick(means, key=means.__getitem__)
            bold = [keys[i] for i in range(len(keys)) if body[i][column].startswith("**")]
            assert bold == [best]
            # References are floors, never bolded.
            assert not body[-1][column].startswith("**") and not body[-2][column].startswith("**")


def test_reference_rows_average_per_seed_first(fake: FakeResults, report: Any) -> None:
    body = _md_section(report.documents["md"].read_text(), "**Table I — preset table1.**")
    for offset, name in ((-2, "median"), (-1, "analytical")):
        md_row = body[offset]
        assert md_row[0].lower().startswith(name)
        for c_index, condition in enumerate(("seen", "unseen")):
            for m_index, metric in enumerate(("log10_accuracy", "nmse")):
                per_seed = []
                for seed in SEEDS:
                    runs = _rows(fake, preset="table1", condition=condition, seed=seed)
                    per_seed.append(np.mean([r[f"ref_{name}_{metric}"] for r in runs]))
                mean, std = _mean_std(per_seed)
                assert md_row[2 + 2 * c_index + m_index] == _fmt(mean, std)


def test_table2_cells_and_its_latex(fake: FakeResults, report: Any) -> None:
    cells = report.tables["tableII"]
    for model in MODELS:
        for inputs in ("Image", "ALL"):
            runs = _rows(fake, preset="table2", model=model, inputs=inputs)
            mean, std = _mean_std([r["test_nmse"] for r in runs])
            got = cells[
                (cells["model"] == model)
                & (cells["inputs"] == inputs)
                & (cells["metric"] == "nmse")
            ]
            assert got["mean"].iloc[0] == pytest.approx(mean)
            assert got["std"].iloc[0] == pytest.approx(std)
    # Only Image and ALL were run: the other strategies are not invented as rows.
    assert set(cells["inputs"].dropna()) == {"Image", "ALL"}
    text = (report.out_dir / "tables" / "tableII.tex").read_text()
    assert r"\toprule" in text and r"\bottomrule" in text and r"\mathbf{" in text


def test_failed_rows_are_excluded_and_listed(fake: FakeResults, report: Any) -> None:
    cells = report.tables["tableI"]
    assert (cells["mean"] < 1.0).all()  # the failed row's 99.0 never entered a mean
    markdown = report.documents["md"].read_text()
    failed = _md_section(markdown, "**Runs that did not complete.**")
    assert len(failed) == 1
    assert "CUDA out of memory (fake)" in failed[0][-1]
    assert report.n_failed == 1


# ============================================================================ Table III
def test_table3_from_the_store_header(fake: FakeResults, report: Any) -> None:
    cells = report.tables["table3"]
    body = _md_section(report.documents["md"].read_text(), "**Table III — Shore-hardness data.**")
    assert [r[0] for r in body] == [LABELS[m] for m in MODELS]
    for row, model in zip(body, MODELS, strict=True):
        runs = _rows(fake, preset="shore", model=model)
        for column, metric in ((3, "nmse"), (4, "r2")):
            mean, std = _mean_std([r[f"test_{metric}"] for r in runs])
            got = cells[(cells["model"] == model) & (cells["metric"] == metric)]
            assert got["mean"].iloc[0] == pytest.approx(mean)
            assert _unbold(row[column]) == _fmt(mean, std)
    # Shore runs are Table III material only: not mixed into Table I.
    assert not report.tables["tableI"]["store"].astype(str).str.contains("shore").any()


# ============================================================================ Fig. 6 / 7
def test_rolling_window_and_shape_numbers(fake: FakeResults, report: Any) -> None:
    fig6 = report.tables["fig6"]
    assert len(fig6) == 2 * 7
    for model in ("vgg_lstm", "res_tf"):
        for window in range(7):
            runs = _rows(fake, preset="rolling-window", model=model, subset=window)
            mean, std = _mean_std([r["test_nmse"] for r in runs])
            got = fig6[(fig6["model"] == model) & (fig6["subset"] == window)]
            assert got["mean"].iloc[0] == pytest.approx(mean)
            assert got["std"].iloc[0] == pytest.approx(std)
    fig7 = report.tables["fig7"]
    for model in ("vgg_lstm", "res_tf"):
        for inputs in ("Image", "ALL"):
            for shape in ("Sphere", "Cylinder"):
                runs = _rows(fake, preset="shape-test", model=model, inputs=inputs, subset=shape)
                mean, _ = _mean_std([r["test_nmse"] for r in runs])
                got = fig7[
                    (fig7["model"] == model)
                    & (fig7["inputs"] == inputs)
                    & (fig7["subset"] == shape)
                ]
                assert got["mean"].iloc[0] == pytest.approx(mean)
    softhard = report.tables["softhard-subsets"]
    runs = _rows(fake, preset="softhard", subset="soft")
    mean, std = _mean_std([r["test_nmse"] for r in runs])
    got = softhard[(softhard["subset"] == "soft") & (softhard["metric"] == "nmse")]
    assert got["mean"].iloc[0] == pytest.approx(mean)


# ============================================================================ Fig. 5 / extras
def test_fig5_uses_the_lowest_nmse_seed_of_balanced_seen(fake: FakeResults, report: Any) -> None:
    fig5 = report.tables["fig5"]
    assert len(fig5) == len(MODELS) * 2
    for row in fig5.itertuples():
        runs = _rows(fake, preset="table2", model=row.model, inputs=row.inputs)
        best = min(runs, key=lambda r: r["test_nmse"])
        assert row.seed == best["seed"]
        assert row.nmse == pytest.approx(best["test_nmse"])
        predictions = pd.read_csv(fake.root / best["run_dir"] / "predictions.csv")
        test = predictions[predictions["split"] == "test"]
        d = np.abs(np.log10(test["pred_pa"]) - np.log10(test["modulus_pa"]))
        inside = float(np.mean(d <= 9 * math.sqrt(best["test_nmse"]) + 1e-9))
        assert row.inside_band == pytest.approx(inside)
        assert row.n == len(test)


def test_per_material_table_aggregates_groups_csv(fake: FakeResults, report: Any) -> None:
    cells = report.tables["groups-nmse"]
    runs = _rows(fake, preset="table2", model="vgg_lstm", inputs="ALL")
    values = []
    for run in runs:
        groups = pd.read_csv(fake.root / run["run_dir"] / "groups.csv")
        hit = groups[(groups["grouping"] == "material") & (groups["group"] == "Rubber")]
        values += hit["nmse"].tolist()
    mean, std = _mean_std(values)
    got = cells[
        (cells["group"] == "Rubber") & (cells["model"] == "vgg_lstm") & (cells["inputs"] == "ALL")
    ]
    assert got["mean"].iloc[0] == pytest.approx(mean)
    assert got["std"].iloc[0] == pytest.approx(std)
    assert {"soft", "hard"} <= set(cells.loc[cells["grouping"] == "soft_hard", "group"])


# ============================================================================ files
def test_every_figure_is_a_real_png(report: Any) -> None:
    import matplotlib.image

    expected = {"fig5", "fig6", "fig7", "fig8", "learning-curves"}
    assert expected <= set(report.figures)
    assert any(key.startswith("fig1-toy_store") for key in report.figures)
    assert any(key.startswith("fig1-shore_store") for key in report.figures)
    for key, path in report.figures.items():
        data = Path(path).read_bytes()
        assert data[:8] == PNG_MAGIC, path
        pixels = matplotlib.image.imread(path)[..., :3]
        assert min(pixels.shape[:2]) >= 200, (key, pixels.shape)
        # Drawn on: many distinct colours, and ink on a good part of the canvas.
        rgb = (pixels.reshape(-1, 3) * 255).astype(np.int64)
        colours = np.unique(rgb[:, 0] * 65536 + rgb[:, 1] * 256 + rgb[:, 2])
        assert len(colours) > 20, (key, len(colours))
        assert np.mean(pixels.mean(axis=-1) < 0.9) > 0.02, key


def _band_share(predictions: pd.DataFrame, span_decades: float, nmse: float) -> float:
    d = np.abs(np.log10(predictions["pred_pa"]) - np.log10(predictions["modulus_pa"]))
    return float(np.mean(d <= span_decades * math.sqrt(nmse) + 1e-9))


@pytest.mark.parametrize(
    "key, preset, span_decades",
    [("fig5", "table2", 9.0), ("fig8", "shore", 4.0)],  # label ranges 1e3-1e12, 1e3-1e7 Pa
)
def test_scatter_figure_data_files_match_their_runs(
    fake: FakeResults, report: Any, key: str, preset: str, span_decades: float
) -> None:
    """tables/fig5.csv and fig8.csv (what the figures draw) against the runs' own files."""
    table = pd.read_csv(report.out_dir / "tables" / f"{key}.csv")
    panels = {(r["model"], r["inputs"]) for r in _rows(fake, preset=preset)}
    assert set(zip(table["model"], table["inputs"], strict=True)) == panels
    assert len(table) == len(panels)
    for row in table.itertuples():
        runs = _rows(fake, preset=preset, model=row.model, inputs=row.inputs)
        best = min(runs, key=lambda r: r["test_nmse"])
        assert row.seed == best["seed"]
        run_dir = fake.root / best["run_dir"]  # relative rows resolve from the results' parent
        predictions = pd.read_csv(run_dir / "predictions.csv").query("split == 'test'")
        d = np.log10(predictions["pred_pa"]) - np.log10(predictions["modulus_pa"])
        nmse = float(np.mean((d / span_decades) ** 2))
        assert row.nmse == pytest.approx(nmse, rel=1e-9)
        assert row.n == len(predictions)
        assert row.inside_band == pytest.approx(_band_share(predictions, span_decades, nmse))
        assert Path(row.run_dir).name == run_dir.name


@pytest.mark.parametrize(
    "key, preset, by", [("fig6", "rolling-window", "subset"), ("fig7", "shape-test", "subset")]
)
def test_box_plot_data_files_match_their_runs(
    fake: FakeResults, report: Any, key: str, preset: str, by: str
) -> None:
    """tables/fig6.csv and fig7.csv: one row per box, mean/std over the seeds' rows."""
    table = pd.read_csv(report.out_dir / "tables" / f"{key}.csv")
    runs = _rows(fake, preset=preset)
    boxes = {(r["model"], r["inputs"], str(r[by])) for r in runs}
    got = set(zip(table["model"], table["inputs"], table[by].astype(str), strict=True))
    assert got == boxes and len(table) == len(boxes)
    for row in table.itertuples():
        values = [
            r["test_nmse"]
            for r in runs
            if (r["model"], r["inputs"], str(r[by])) == (row.model, row.inputs, str(row.subset))
        ]
        mean, std = _mean_std(values)
        assert row.mean == pytest.approx(mean, rel=1e-12) and row.metric == "nmse"
        assert row.std == pytest.approx(std, rel=1e-12) and row.n == len(values)


def test_documents_provenance_and_embedding(fake: FakeResults, report: Any) -> None:
    markdown = report.documents["md"].read_text()
    for needle in (
        "## Provenance",
        "`table1` (",
        "`table2` (",
        str(fake.store.path),
        "source toy",
        "source yuan",
        "random init (no ImageNet weights)",
        f"tactile-compliance {__version__}",
        "Seeds per cell: 3–3",
    ):
        assert needle in markdown, needle
    # Every table carries its own "how produced" line.
    assert markdown.count("*How produced:*") >= len(report.tables)
    html = report.documents["html"].read_text()
    assert html.count("data:image/png;base64,") == len(report.figures)
    assert 'src="figures/' not in html  # self-contained: no file links
    tex = report.documents["tex"].read_text()
    assert tex.startswith(r"\documentclass") and tex.rstrip().endswith(r"\end{document}")
    assert tex.count(r"\includegraphics") == len(report.figures)
    assert not report.notes, report.notes


# ============================================================================ partial data
def test_partial_results_skip_with_notes(fake: FakeResults, tmp_path: Path) -> None:
    partial = ResultsStore(tmp_path / "partial")
    for row in fake.rows:
        if row["preset"] == "table1":
            partial.record(row)
    summary = build_report(partial.path, tmp_path / "out", formats="md,tex", strict=True)
    text = summary.documents["md"].read_text()
    assert "tableI" in summary.tables and "tableII" not in summary.tables
    joined = "\n".join(summary.notes)
    for preset in ("`table2`", "`rolling-window`", "`shape-test`", "`new-dataset`"):
        assert preset in joined, preset
    assert "Fig. 5 skipped" in joined  # table1 rows here carry no run directories
    assert "> **Note:**" in text
    assert set(summary.documents) == {"md", "tex"}


def test_empty_and_missing_results(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    summary = build_report(tmp_path / "empty", tmp_path / "out", strict=True)
    assert summary.n_rows == 0 and not summary.figures and not summary.tables
    assert "No complete runs yet" in summary.documents["md"].read_text()
    assert summary.documents["html"].exists()
    with pytest.raises(FileNotFoundError):
        build_report(tmp_path / "nope", tmp_path / "out2")
    with pytest.raises(ValueError, match="unknown report format"):
        build_report(tmp_path / "empty", tmp_path / "out3", formats="md,pdf")


def test_cell_formatting_regression() -> None:
    # The paper's look: 4 decimals, "mean ± std".
    from tactile_compliance.evaluation.render import format_mean_std

    assert format_mean_std(0.899, 0.0094) == "0.8990 ± 0.0094"
    assert format_mean_std(0.5, float("nan")) == "0.5000"
    assert re.fullmatch("–", format_mean_std(None))


def test_presets_are_never_pooled(fake: FakeResults, tmp_path: Path) -> None:
    mixed = ResultsStore(tmp_path / "mixed")
    main = [r for r in fake.rows if r["preset"] == "table1" and r["status"] == "complete"]
    for row in main:
        mixed.record(row)
    quick = []
    for seed in (0, 1):
        row = {
            **main[0],
            "key": f"quick{seed}",
            "preset": "table1-quick",
            "seed": seed,
            "test_nmse": 0.5 + 0.1 * seed,
        }
        mixed.record(row)
        quick.append(row)
    summary = build_report(mixed.path, tmp_path / "out", formats="md", strict=True)
    tables = {k: v for k, v in summary.tables.items() if k.startswith("tableI-")}
    assert len(tables) == 2
    by_preset = {t["preset"].iloc[0]: t for t in tables.values()}
    cell = by_preset["table1-quick"]
    got = cell[(cell["metric"] == "nmse") & (cell["model"] == main[0]["model"])]
    assert len(got) == 1 and got["mean"].iloc[0] == pytest.approx(0.55)
    assert got["std"].iloc[0] == pytest.approx(np.std([0.5, 0.6], ddof=1))
    full = by_preset["table1"]
    runs = _rows(
        fake,
        preset="table1",
        model=main[0]["model"],
        inputs=main[0]["inputs"],
        condition=main[0]["condition"],
    )
    got = full[
        (full["model"] == main[0]["model"])
        & (full["inputs"] == main[0]["inputs"])
        & (full["condition"] == main[0]["condition"])
        & (full["metric"] == "nmse")
    ]
    assert got["mean"].iloc[0] == pytest.approx(np.mean([r["test_nmse"] for r in runs]))
    assert "**Table I — preset table1-quick.**" in summary.documents["md"].read_text()


def test_a_broken_run_dir_becomes_a_note_not_a_crash(fake: FakeResults, tmp_path: Path) -> None:
    broken = ResultsStore(tmp_path / "broken")
    run_dir = tmp_path / "runs" / "bad"
    run_dir.mkdir(parents=True)
    (run_dir / "predictions.csv").write_text("sample_id,split\n1,test\n")  # no modulus columns
    broken.record({**_rows(fake, preset="table2")[0], "run_dir": str(run_dir)})
    summary = build_report(broken.path, tmp_path / "out", formats="md,html")
    assert any(note.startswith("Fig. 5 could not be built") for note in summary.notes)
    assert "tableII" in summary.tables  # the rest of the report is still there
    with pytest.raises(KeyError):
        build_report(broken.path, tmp_path / "out2", formats="md", strict=True)


def test_report_command(fake: FakeResults, tmp_path: Path) -> None:
    from typer.testing import CliRunner

    from tactile_compliance.cli import app

    out = tmp_path / "cli-report"
    result = CliRunner().invoke(
        app, ["report", str(fake.results.path), "--out", str(out), "--format", "md,html,tex"]
    )
    assert result.exit_code == 0, result.output
    assert {p.name for p in out.iterdir()} >= {"report.md", "report.html", "report.tex"}
    again = CliRunner().invoke(app, ["report", str(fake.results.path), "--out", str(out), "--json"])
    assert again.exit_code == 0, again.output
    written = json.loads(again.stdout)
    assert written["documents"] == {"md": str(out / "report.md"), "html": str(out / "report.html")}
    assert all(Path(png).is_file() for png in written["figures"].values())
    missing = CliRunner().invoke(app, ["report", str(tmp_path / "nothing")])
    assert missing.exit_code == 2 and "error" in missing.output


def test_rows_beyond_the_paper_are_marked(tmp_path: Path) -> None:
    from tactile_compliance.data.inputs import InputStrategy
    from tactile_compliance.evaluation.tables import inputs_label

    for strategy in InputStrategy:
        expected = strategy.value if strategy.in_paper else f"{strategy.value} (beyond the paper)"
        assert inputs_label(strategy.value) == expected
    fake = FakeResults(tmp_path)
    for model, inputs in (("top10nn", "ALL"), ("scalar_mlp", "FW"), ("top10nn", "DepthFW")):
        for seed in SEEDS:
            fake.record(
                preset="table1",
                model=model,
                inputs=inputs,
                condition="unseen",
                sampling="random",
                seed=seed,
                run_dir=None,
                **fake.metrics(),
            )
    build_report(fake.results.path, tmp_path / "out", formats=("md",))
    markdown = (tmp_path / "out" / "report.md").read_text()
    rows = {(r[0], r[1]) for r in _md_section(markdown, "Table I")}
    assert ("Top10NN", "ALL") in rows
    assert ("Scalar MLP", "FW (beyond the paper)") in rows
    assert ("Top10NN", "DepthFW (beyond the paper)") in rows


def test_a_single_run_directory_is_reported_with_its_figure(
    fake: FakeResults, tmp_path: Path
) -> None:
    """``report RUN`` (issue 42): a run directory, not a results store, gets its metrics
    table and its predicted-against-true figure (it was an empty report)."""
    from typer.testing import CliRunner

    from tactile_compliance.cli import app

    run_dir = tmp_path / "runs" / "top10nn-ALL-seen-random-seed0-abc"
    metrics = _write_run_dir(run_dir, fake.samples, np.random.default_rng(5), 0.4)
    test = {"log10_accuracy": metrics["log10_accuracy"], "nmse": metrics["nmse"], "n": 40}
    result = {
        "status": "complete",
        "run_name": run_dir.name,
        "model": "top10nn",
        "inputs": "ALL",
        "seed": 0,
        "test": test,
        "val": {"log10_accuracy": 1.0, "nmse": 0.0, "n": 5},
        "reference": {"median": {"log10_accuracy": 0.25, "nmse": 0.5, "n": 40}},
    }
    (run_dir / "metrics.json").write_text(json.dumps(result))
    out = tmp_path / "run-report"
    cli = CliRunner().invoke(app, ["report", str(run_dir), "--out", str(out), "--json"])
    assert cli.exit_code == 0, cli.output
    written = json.loads(cli.stdout)
    assert written["complete"] == 1 and written["figures"]["run-scatter"].endswith(".png")
    assert Path(written["figures"]["run-scatter"]).read_bytes().startswith(PNG_MAGIC)
    cells = pd.read_csv(out / "tables" / "run-metrics.csv")
    assert list(cells["row"]) == ["test", "val", "reference: median (test)"]
    assert cells.loc[0, "nmse"] == pytest.approx(metrics["nmse"])
    text = (out / "report.md").read_text()
    assert run_dir.name in text and f"{metrics['nmse']:.4f}" in text
    (run_dir / "predictions.csv").unlink()
    again = build_report(run_dir, tmp_path / "no-predictions", formats="md")
    assert not again.figures and any("no test predictions" in n for n in again.notes)
