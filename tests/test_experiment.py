"""Experiment grids: the YAML format, the packaged presets, and runs on a local Dask cluster
that lose a worker (or the whole driver) midway and still end with every cell done once."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pandas as pd
import pytest

from epoch_trace import (
    committed_epochs,
    default_sigint,
    read_trace,
    traced_env,
    wait_until_midway,
)
from tactile_compliance.config import ConfigError, load_config, save_config
from tactile_compliance.runs.results import ResultsStore
from tactile_compliance.training.experiment import (
    ExperimentError,
    plan_experiment,
    run_experiment,
)
from tactile_compliance.training.experiment_file import (
    expand_experiment,
    list_experiment_presets,
    load_experiment,
)
from toy_store import make_toy_store

TESTS_DIR = Path(__file__).resolve().parent

# A tiny grid: Top10NN (a few CPU seconds per run) and a frozen-backbone Res-Tf (cached
# features), two seeds. One cell is broken on purpose: the toy store has no Hex objects.
TINY = """
description: tiny test grid
config: default
set:
  augmentation.enabled: false
  training.batch_size: 16
  training.lr: 1.0e-3
  training.patience: 100
grid:
  model.name: [top10nn, res_tf]
  inputs: [Image, ALL]
seeds: 2
rules:
  - when: {model.name: top10nn}
    set: {data.image_size: [72, 72], training.max_epochs: 4}
  - when: {model.name: res_tf}
    set: {data.image_size: [32, 32], model.freeze_backbone: true, training.max_epochs: 3,
          model.hparams: {num_layers: 1, num_heads: 2, embedding_dim: 32, output_dim: 32,
                          dim_feedforward: 64, decoder_sizes: [32]}}
  - when: {model.name: res_tf, inputs: ALL}
    set: {split.subset: Hex}
quick:
  seeds: 1
  set: {training.batch_size: 8}
"""


@pytest.fixture(scope="module")
def toy_store(tmp_path_factory):
    return make_toy_store(tmp_path_factory.mktemp("toy") / "store")


@pytest.fixture()
def tiny(tmp_path):
    path = tmp_path / "tiny.yaml"
    path.write_text(TINY)
    return path


# ---------------------------------------------------------------------------- format
def test_packaged_presets_expand_to_valid_cells():
    assert set(list_experiment_presets()) >= {
        "table1",
        "table2",
        "rolling-window",
        "shape-test",
        "new-dataset",
    }
    sizes = {
        "table1": 360,  # 3 models x 4 inputs x 3 object conditions x 10 seeds
        "table2": 360,
        "rolling-window": 210,
        "shape-test": 240,
        "new-dataset": 30,
    }
    for name, size in sizes.items():
        full = expand_experiment(load_experiment(name))
        quick = expand_experiment(load_experiment(name, quick=True))
        assert len(full) == size, name
        assert len(quick) == size // 5, name  # 2 seeds instead of 10
        assert len({c.key for c in full}) == len(full)
        for cell in quick:
            cfg = cell.cfg
            # Early stopping ends every quick run: a short budget, and patience below it.
            assert cfg.training.max_epochs <= 40
            assert cfg.training.patience < cfg.training.max_epochs
            if cfg.model.name == "top10nn":
                assert min(cfg.data.image_size) >= 65  # the Top10 CNN needs >= 65 px
            else:
                assert cfg.model.freeze_backbone and max(cfg.data.image_size) <= 64
    table1 = expand_experiment(load_experiment("table1"))
    # The paper's Seen/UnSeen as three object conditions, every (model, inputs, seed) in each.
    conditions = {(c.cfg.split.condition, c.cfg.split.grouping) for c in table1}
    assert conditions == {("seen", "per_sample"), ("seen", "grasp"), ("unseen", "grasp")}
    for condition in conditions:
        same = [c for c in table1 if (c.cfg.split.condition, c.cfg.split.grouping) == condition]
        assert len(same) == 120
    cells = {
        (c.cfg.model.name, c.cfg.inputs, c.cfg.split.condition): c.cfg
        for c in table1
        if c.cfg.split.grouping == "grasp"
    }
    assert cells["vgg_lstm", "ALL", "seen"].training.lr == pytest.approx(3e-4)
    assert cells["res_tf", "Image", "unseen"].model.hparams["num_layers"] == 5
    assert cells["res_tf", "ALL", "seen"].model.hparams == {}
    assert cells["top10nn", "ImageF", "seen"].training.lr == pytest.approx(3e-6)
    assert Path(cells["top10nn", "ALL", "seen"].data.store).name == "ym"
    assert {c.cfg.sampling.strategy for c in expand_experiment(load_experiment("table2"))} == {
        "balanced"
    }
    shore = expand_experiment(load_experiment("new-dataset", quick=True))
    assert {c.cfg.inputs for c in shore} == {"Image"}
    assert shore[0].cfg.data.label_range_pa == (1e3, 1e7)
    windows = expand_experiment(load_experiment("rolling-window", quick=True))
    assert sorted({c.cfg.split.subset for c in windows}) == list(range(7))
    for name in ("rolling-window", "shape-test"):  # one condition: seen, grasp-grouped
        cells = expand_experiment(load_experiment(name, quick=True))
        assert {(c.cfg.split.condition, c.cfg.split.grouping) for c in cells} == {("seen", "grasp")}


def test_linked_grid_axis_sets_several_keys_together(tmp_path):
    (tmp_path / "linked.yaml").write_text(
        textwrap.dedent("""
        description: linked
        grid:
          inputs: [Image, ALL]
          objects:
            - {split.condition: seen, split.grouping: per_sample}
            - {split.condition: unseen}
          model.hparams: [{dropout: 0.1}, {dropout: 0.2}]   # a mapping-valued config key
        seeds: 1
        rules:
          - when: {split.grouping: per_sample}
            set: {training.lr: 0.5}
    """)
    )
    cells = expand_experiment(load_experiment(tmp_path / "linked.yaml"))
    assert len(cells) == 2 * 2 * 2
    first = cells[0]
    assert first.axes == {
        "inputs": "Image",
        "split.condition": "seen",
        "split.grouping": "per_sample",
        "model.hparams": {"dropout": 0.1},
        "seed": 0,
    }
    assert first.label == "top10nn Image seen per_sample random seed 0"
    per_sample = [c for c in cells if c.cfg.split.grouping == "per_sample"]
    assert len(per_sample) == 4 and {c.cfg.training.lr for c in per_sample} == {0.5}
    unseen = [c for c in cells if c.cfg.split.condition == "unseen"]
    assert len(unseen) == 4 and {c.cfg.split.grouping for c in unseen} == {"grasp"}
    assert {c.cfg.model.hparams["dropout"] for c in unseen} == {0.1, 0.2}
    # --where matches the keys a linked axis sets.
    only = expand_experiment(
        load_experiment(tmp_path / "linked.yaml"), where=["split.grouping=per_sample"]
    )
    assert [c.key for c in only] == [c.key for c in per_sample]


def test_grid_rules_overrides_filters_and_plain_configs(tiny, tmp_path, toy_store):
    spec = load_experiment(tiny)
    cells = expand_experiment(spec, store=toy_store.path, output_dir=tmp_path / "out")
    assert len(cells) == 8 and [c.axes["seed"] for c in cells[:2]] == [0, 1]
    by_label = {c.label: c.cfg for c in cells}
    assert by_label["res_tf ALL seen random subset Hex seed 0"].model.freeze_backbone
    assert by_label["top10nn Image seen random seed 1"].data.image_size == (72, 72)
    assert all(c.cfg.data.store == str(toy_store.path.resolve()) for c in cells)
    # Command-line overrides come last; filters keep matching cells only.
    cells = expand_experiment(
        spec, seeds=3, overrides=["training.lr=0.5"], where=["model.name=top10nn", "inputs=[ALL]"]
    )
    assert [(c.cfg.inputs, c.cfg.seed, c.cfg.training.lr) for c in cells] == [
        ("ALL", 0, 0.5),
        ("ALL", 1, 0.5),
        ("ALL", 2, 0.5),
    ]
    # The quick section merges over the file.
    quick = expand_experiment(load_experiment(tiny, quick=True))
    assert len(quick) == 4 and {c.cfg.training.batch_size for c in quick} == {8}
    # A plain config file (what `tune` writes) is a one-cell experiment crossed with seeds.
    best = save_config(load_config("default", ["model.name=res_tf"]), tmp_path / "best.yaml")
    plain = expand_experiment(load_experiment(best), seeds=3)
    assert [(c.cfg.model.name, c.cfg.seed) for c in plain] == [("res_tf", s) for s in range(3)]
    # `extends` + `include`: a tuned-overrides file applied to one model only.
    (tmp_path / "tuned.yaml").write_text("training.lr: 0.25\nmodel.hparams: {num_layers: 2}\n")
    (tmp_path / "child.yaml").write_text(
        textwrap.dedent("""
        extends: tiny.yaml
        grid: {inputs: [Image]}
        rules:
          - when: {model.name: res_tf}
            include: tuned.yaml
    """)
    )
    child = {c.label: c.cfg for c in expand_experiment(load_experiment(tmp_path / "child.yaml"))}
    assert len(child) == 4
    assert child["res_tf Image seen random seed 0"].training.lr == 0.25
    assert child["res_tf Image seen random seed 0"].model.hparams == {"num_layers": 2}
    assert child["top10nn Image seen random seed 0"].training.lr == pytest.approx(1e-3)


def test_paper_settings_apply_before_rules(tmp_path):
    (tmp_path / "paper.yaml").write_text(
        textwrap.dedent("""
        description: paper settings
        set: {training.lr: 0.5}
        grid: {model.name: [top10nn, vgg_lstm, res_tf], inputs: [Image, ALL]}
        paper_settings: true
        rules:
          - when: {model.name: res_tf, inputs: ALL}
            set: {training.lr: 0.25}
    """)
    )
    spec = load_experiment(tmp_path / "paper.yaml")
    assert spec.paper_settings and spec.to_dict()["paper_settings"] is True
    cells = {(c.cfg.model.name, c.cfg.inputs): c.cfg for c in expand_experiment(spec)}
    vgg = cells["vgg_lstm", "ALL"].training
    assert (vgg.lr, vgg.batch_size, vgg.gamma) == (3e-4, 16, 0.97974)
    assert cells["top10nn", "Image"].training.lr == 3e-6  # over `set`
    assert cells["res_tf", "Image"].training.lr == 8e-5
    assert cells["res_tf", "Image"].model.hparams["output_dim"] == 1024
    assert cells["res_tf", "ALL"].training.lr == 0.25  # rules come after
    assert cells["res_tf", "ALL"].model.hparams == {}
    overridden = expand_experiment(spec, overrides=["training.batch_size=4"])
    assert {c.cfg.training.batch_size for c in overridden} == {4}  # --set comes last
    (tmp_path / "bad.yaml").write_text("description: x\npaper_settings: sure\n")
    with pytest.raises(ConfigError, match="paper_settings"):
        load_experiment(tmp_path / "bad.yaml")
    (tmp_path / "unknown.yaml").write_text("grid: {model.name: [resnet]}\npaper_settings: true\n")
    with pytest.raises(ConfigError, match="unknown model 'resnet'"):
        expand_experiment(load_experiment(tmp_path / "unknown.yaml"))


def test_table1_paper_settings_equal_the_published_values(tmp_path):
    # What table1 spelled out per model before the settings moved onto the model classes.
    (tmp_path / "literal.yaml").write_text(
        textwrap.dedent("""
        extends: table1
        paper_settings: false
        rules:
          - when: {model.name: vgg_lstm}
            set: {training.lr: 3.0e-4, training.batch_size: 16, training.gamma: 0.97974}
          - when: {model.name: res_tf}
            set: {training.lr: 1.1e-4, training.batch_size: 24, training.gamma: 0.977}
          - when: {model.name: res_tf, inputs: Image}
            set:
              model.hparams: {num_layers: 5, num_heads: 4, embedding_dim: 256,
                              output_dim: 1024, decoder_sizes: [256]}
              training.lr: 8.0e-5
              training.batch_size: 40
              training.gamma: 0.962
    """)
    )
    literal = expand_experiment(load_experiment(tmp_path / "literal.yaml"), seeds=1)
    packaged = expand_experiment(load_experiment("table1"), seeds=1)
    assert [c.key for c in literal] == [c.key for c in packaged] and len(packaged) == 36


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("grid: {model.name: [top10nn]}\nsets: {}\n", "unknown key"),
        ("set: {training.lrr: 1}\n", "training.lrr"),
        ("grid: {split.condition: [seen, sideways]}\n", "split.condition"),
        ("grid: {objects: [{split.conditon: seen}]}\n", "split.conditon"),
        ("grid: {objects: [{split.condition: seen}, seen]}\n", "linked axis"),
        ("grid: {objects: [{inputs: ALL}], inputs: [Image]}\n", "both set 'inputs'"),
        (
            "grid: {objects: [{split.condition: unseen, split.grouping: per_sample}]}\n",
            "per_sample only applies",
        ),
        ("grid: {seed: [1, 2]}\n", "seeds"),
        ("seeds: 0\n", "seeds must be"),
        ("rules:\n  - when: {model.name: top10nn}\n", "changes nothing"),
        ("rules:\n  - when: {model.nam: x}\n    set: {seed: 1}\n", "model.nam"),
        # The config's YAML reader: a repeated key would silently drop one of the two.
        ("set: {training.lr: 1.0e-3}\nset: {training.lr: 3.0e-4}\n", "duplicate key"),
        ("extends: bad.yaml\n", "circular 'extends' chain"),
        ("extends: [table1]\n", "'extends' must be an experiment name or path"),
    ],
)
def test_bad_experiment_files_fail_before_running(tmp_path, text, message):
    path = tmp_path / "bad.yaml"
    path.write_text("description: bad\n" + text)
    with pytest.raises(ConfigError, match=message):
        expand_experiment(load_experiment(path))


def test_unknown_preset_missing_quick_and_missing_store(tmp_path, tiny):
    with pytest.raises(ConfigError, match="table1"):
        load_experiment("tabel1")
    (tmp_path / "noquick.yaml").write_text("description: x\nseeds: 1\n")
    with pytest.raises(ConfigError, match="no 'quick'"):
        load_experiment(tmp_path / "noquick.yaml", quick=True)
    with pytest.raises(ExperimentError, match="store not found"):
        run_experiment(tiny, store=tmp_path / "nowhere", output_dir=tmp_path / "o", progress=False)


# ---------------------------------------------------------------------------- on Dask
def _kill_first_run_midway(out: Path, stop: threading.Event, killed: dict) -> None:
    """Kill the worker process of the first cell seen between two epochs (SIGKILL)."""
    while not stop.is_set():
        for attempts in out.glob("*/attempts.json"):
            run_dir = attempts.parent
            if (run_dir / "checkpoints" / "last.ckpt").exists() and not (
                run_dir / "metrics.json"
            ).exists():
                pid = json.loads(attempts.read_text())["history"][-1]["pid"]
                os.kill(pid, signal.SIGKILL)
                killed.update(run_dir=run_dir, pid=pid)
                return
        time.sleep(0.02)


def _rows(results: Path) -> dict[str, dict]:
    return {row["key"]: row for row in ResultsStore(results).rows()}


@pytest.mark.slow  # 108 s at load 6-8; its parts run by default in cheaper tests (docs/testing.md)
def test_grid_survives_a_killed_worker_and_reruns_idempotently(tiny, tmp_path, toy_store):
    out = tmp_path / "out"
    stop, killed = threading.Event(), {}
    watcher = threading.Thread(target=_kill_first_run_midway, args=(out, stop, killed))
    watcher.start()
    try:
        summary = run_experiment(
            tiny, store=toy_store.path, output_dir=out, workers=2, progress=False
        )
    finally:
        stop.set()
        watcher.join()
    assert killed, "no run was caught between two epochs; the test did not kill anything"
    plan = plan_experiment(tiny, store=toy_store.path, output_dir=out)
    rows = _rows(summary.results_path)
    # Every cell has exactly one row (rows are keyed by cell); the broken ones say why.
    assert sorted(rows) == sorted(c.key for c in plan.cells)
    broken = {c.key for c in plan.cells if c.cfg.split.subset == "Hex"}
    assert len(broken) == 2
    assert summary.completed == 6 and summary.failed == 2 and summary.skipped == 0
    for key, row in rows.items():
        if key in broken:
            assert row["status"] == "failed" and "Hex" in row["error"] and row["traceback"]
        else:
            assert row["status"] == "complete" and row["test_n"] > 0, row
    # The killed run was restarted by Dask (resuming from its checkpoint) and finished.
    killed_row = next(r for r in rows.values() if Path(r["run_dir"]) == killed["run_dir"])
    assert killed_row["status"] == "complete" and killed_row["attempts"] == 2
    max_epochs = load_config(killed["run_dir"] / "config.yaml").training.max_epochs
    assert killed_row["epochs_trained"] == max_epochs
    log = killed["run_dir"] / "logs" / "metrics.csv"
    if log.exists():  # epochs logged before the kill may be lost, but none is repeated
        epochs = pd.read_csv(log).dropna(subset=["val_nmse"])["epoch"].astype(int).tolist()
        assert len(epochs) == len(set(epochs))
    # One run directory per cell (each records its attempts), nothing else trained; the
    # two cells whose config fails its checks write no config.yaml.
    assert len(list(out.glob("*/attempts.json"))) == 8
    assert len(list(out.glob("*/config.yaml"))) == 6

    # Re-run: complete cells are skipped untouched, failed ones are retried (and recorded).
    again = run_experiment(tiny, store=toy_store.path, output_dir=out, workers=1, progress=False)
    assert (again.skipped, again.completed, again.failed) == (6, 0, 2)
    after = _rows(summary.results_path)
    for key, row in rows.items():
        if key in broken:
            assert after[key]["attempts"] == row["attempts"] + 1
        else:
            assert after[key] == row
    assert len(again.table()) == 8
    assert "2 failed" in again.format() and "FAILED res_tf ALL" in again.format()


# ------------------------------------------------------------ the driver interrupted
# Two seeds of Top10NN, three epochs each: cells run one after another on one worker, so
# the driver can be caught with one cell complete and the next one midway.
KILL_GRID = """
description: two cells to interrupt
config: default
set:
  model.name: top10nn
  augmentation.enabled: false
  data.image_size: [72, 72]
  training.batch_size: 8
  training.lr: 1.0e-3
  training.max_epochs: 3
  training.patience: 100
seeds: 2
"""
KILL_EPOCHS = 3
#: Row fields that differ between two runs of the same cell (when, how long, where).
VOLATILE = ("finished", "wall_time_s", "attempts", "run_dir", "host")


@pytest.fixture(scope="module")
def kill_setup(tmp_path_factory):
    root = tmp_path_factory.mktemp("kill")
    grid = root / "grid.yaml"
    grid.write_text(KILL_GRID)
    store = make_toy_store(root / "store", n_objects=8, grasps=2, size=(72, 72))
    return grid, store


def _experiment(grid: Path, store, out: Path, trace: Path) -> subprocess.Popen:
    """``tactile-compliance experiment`` as a user runs it, in its own process group (the
    driver and its Dask workers), every training epoch traced."""
    command = [sys.executable, "-m", "tactile_compliance.cli", "experiment", str(grid)]
    command += ["--store", str(store.path), "--out", str(out), "--workers", "1"]
    return subprocess.Popen(
        command,
        env=traced_env(trace.parent / "site", trace),
        start_new_session=True,
        preexec_fn=default_sigint,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )


def _comparable(row: dict) -> dict:
    return {k: v for k, v in row.items() if k not in VOLATILE}


@pytest.fixture(scope="module")
def uninterrupted_grid(kill_setup, tmp_path_factory):
    grid, store = kill_setup
    root = tmp_path_factory.mktemp("uninterrupted-grid")
    proc = _experiment(grid, store, root / "out", root / "trace")
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err[-3000:]
    return _rows(root / "results")


@pytest.mark.parametrize("signum", [signal.SIGKILL, signal.SIGINT], ids=["SIGKILL", "SIGINT"])
def test_interrupted_driver_resumes_and_ends_as_if_uninterrupted(
    kill_setup, uninterrupted_grid, tmp_path, signum
):
    """SIGKILL (the machine went down) or SIGINT (Ctrl-C in the terminal: the whole
    foreground process group) the `experiment` command with one cell complete and the
    next one midway; the same command again trains nothing twice and ends with the
    uninterrupted run's results store."""
    grid, store = kill_setup
    out, results, trace = tmp_path / "out", tmp_path / "results", tmp_path / "trace"
    proc = _experiment(grid, store, out, trace)
    try:
        midway = wait_until_midway(
            proc,
            trace,
            lambda: (results / "rows").is_dir() and bool(_rows(results)),
            timeout_s=240,
            what="the grid",
        )
    finally:
        os.killpg(proc.pid, signum)
        _, err = proc.communicate(timeout=120)
    if signum == signal.SIGINT:
        assert proc.returncode == 130, err[-3000:]  # "interrupted: re-run to continue"
    else:
        assert proc.returncode == -signal.SIGKILL
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:  # no worker process outlives its driver
        try:
            os.killpg(proc.pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.1)
    else:
        pytest.fail("processes of the interrupted experiment are still alive")
    before = _rows(results)
    assert before, "no cell was complete at the interruption"
    # Where each cell stands: complete, some epochs committed, or not started.
    committed = {Path(row["run_dir"]): None for row in before.values()}
    for run_dir in {run_dir for _, _, run_dir in read_trace(trace)} - set(committed):
        committed[run_dir] = committed_epochs(run_dir)
    if signum == signal.SIGKILL:  # caught midway: nothing could finish the cell
        assert not (midway / "metrics.json").exists()
        assert committed[midway] >= 1
    # With SIGINT the Dask workers (which ignore SIGINT) may finish the running cell
    # while the driver shuts the cluster down; it is then complete, and that is fine.
    first_pids = {pid for pid, _, _ in read_trace(trace)}

    rerun = _experiment(grid, store, out, trace)
    _, err = rerun.communicate(timeout=300)
    assert rerun.returncode == 0, err[-3000:]

    # (a) Nothing finished is trained again: a complete cell not at all, a cell with
    # committed epochs from its first uncommitted epoch on, an untouched one from 0.
    again: dict[Path, list[int]] = {}
    for pid, epoch, run_dir in read_trace(trace):
        if pid not in first_pids:
            again.setdefault(run_dir, []).append(epoch)
    assert len(committed | again) == 2  # one run directory per cell
    for run_dir in committed | again:
        start = committed.get(run_dir, 0)
        expected = [] if start is None else list(range(start, KILL_EPOCHS))
        assert again.get(run_dir, []) == expected, (run_dir.name, committed, again)
    rows = _rows(results)
    for key, row in before.items():
        assert rows[key] == row  # untouched, even its finishing time
    attempts = {Path(r["run_dir"]): r["attempts"] for r in rows.values()}
    for run_dir, start in committed.items():
        assert attempts[run_dir] == (2 if start is not None else 1)

    # (b) The results store of the uninterrupted run, cell by cell.
    assert sorted(rows) == sorted(uninterrupted_grid)
    for key, row in rows.items():
        assert row["status"] == "complete"
        assert _comparable(row) == _comparable(uninterrupted_grid[key]), key


def _kill_every_attempt(run_dir: Path, stop: threading.Event, killed: list[int]) -> None:
    """SIGKILL each worker process that starts this cell, as soon as its start is recorded."""
    attempts = run_dir / "attempts.json"
    while not stop.is_set():
        try:
            history = json.loads(attempts.read_text())["history"]
        except (OSError, ValueError, KeyError):
            history = []
        for start in history:
            if start["pid"] not in killed:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(start["pid"], signal.SIGKILL)
                killed.append(start["pid"])
        time.sleep(0.02)


def test_a_cell_whose_worker_keeps_dying_is_recorded_as_failed_and_the_grid_goes_on(
    kill_setup, tmp_path
):
    """Dask re-runs a cell whose worker died on a fresh worker, and gives up after
    ``distributed.scheduler.allowed-failures`` deaths more than one (3 by default; 1 here,
    to keep the test short): the cell is recorded as failed with the reason, and the other
    cells finish."""
    import dask

    grid, store = kill_setup
    out = tmp_path / "out"
    plan = plan_experiment(grid, store=store.path, output_dir=out)
    doomed = plan.cells[1]
    stop, killed = threading.Event(), []
    watcher = threading.Thread(target=_kill_every_attempt, args=(doomed.run_dir, stop, killed))
    watcher.start()
    try:
        # One task per worker at a time, so that a death counts against the doomed cell only.
        with dask.config.set(
            {
                "distributed.scheduler.allowed-failures": 1,
                "distributed.scheduler.worker-saturation": 1.0,
            }
        ):
            summary = run_experiment(
                grid, store=store.path, output_dir=out, workers=1, progress=False
            )
    finally:
        stop.set()
        watcher.join()
    assert len(killed) == 2  # allowed-failures + 1 deaths, then Dask gave up
    assert (summary.completed, summary.failed) == (1, 1)
    rows = _rows(summary.results_path)
    lost = rows[doomed.key]
    assert lost["status"] == "failed" and lost["attempts"] == 2
    assert (
        lost["error"].startswith("KilledWorker") and "died while running this cell" in lost["error"]
    )
    assert "KilledWorker" in lost["traceback"] and lost["run_dir"] == str(doomed.run_dir)
    other = rows[plan.cells[0].key]
    assert other["status"] == "complete" and other["attempts"] == 1
    assert summary.failures == [(doomed.label, lost["error"])]


def test_cells_that_share_a_feature_cache_compute_it_once(tmp_path, toy_store):
    """precompute_features keys caches by data.features.cache_key, the key cached_features
    itself uses: two seeds share one cache, another frame size is another cache."""
    from tactile_compliance.config import config_to_dict
    from tactile_compliance.data.features import FEATURES_DIR
    from tactile_compliance.training.experiment import precompute_features
    from toy_store import tiny_run_config

    frozen = ["model.freeze_backbone=true", "inputs=Image"]

    def cfg(seed: int, size: int) -> dict:
        extra = [*frozen, f"seed={seed}", f"data.image_size=[{size},{size}]"]
        return config_to_dict(tiny_run_config(toy_store.path, tmp_path, "res_tf", extra))

    assert precompute_features([cfg(0, 32), cfg(1, 32)], threads=1) == 1
    assert precompute_features([cfg(0, 32), cfg(1, 32), cfg(0, 40)], threads=1) == 2
    caches = sorted(p.name for p in (toy_store.path / FEATURES_DIR).iterdir())
    assert len(caches) == 2
    assert any("-32x32-" in name for name in caches) and any("-40x40-" in name for name in caches)
