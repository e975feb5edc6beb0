"""Mutation score of the protocol core: which realistic single bugs does the test suite catch?

Each mutation below is one bug that a person could plausibly write into the protocol's
core (splits, balancing, normalisation, metrics, best-epoch restore, augmentation gating),
given as exact source snippets and their replacements. The script

1. checks that every snippet still occurs exactly once in ``src/`` (and fails loudly
   otherwise: a mutation that no longer applies would silently "survive" or be skipped);
2. copies ``src/``, ``tests/``, ``benchmarks/`` and ``pyproject.toml`` to a temporary
   directory (or takes ``src/`` from a git revision with ``--src-rev``); nothing in the
   working tree is ever written, and pytest runs with the copy as its working directory,
   so even its caches land in the copy;
3. runs the chosen test files on the unmutated copy (they must pass: otherwise a
   "caught" mutation would mean nothing);
4. applies one mutation at a time, checks in a subprocess that the mutated module is the
   one imported (``module.__file__`` inside the copy, and the replacement in its source),
   runs the test files with ``-x`` and restores the file;
5. prints a table: mutation, caught (the first failing test) or survived, seconds.

Usage (from the repository root)::

    python benchmarks/mutation_score.py                      # default fast test files
    python benchmarks/mutation_score.py --list               # the mutations only
    python benchmarks/mutation_score.py --only split-grasp-key-includes-shift
    python benchmarks/mutation_score.py --tests tests/test_splits.py tests/test_balance.py
    python benchmarks/mutation_score.py --src-rev HEAD --markdown mutation.md

No dependency beyond the test suite's own (pytest, hypothesis). Results and the command
that produced them are in docs/testing.md.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shutil
import subprocess
import sys
import tarfile
import tempfile
import time
from dataclasses import dataclass, field
from datetime import datetime, timezone
from io import BytesIO
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGE = "tactile_compliance"

#: Test files run against every mutation, cheapest first (pytest stops at the first
#: failure, so a mutation caught by a fast file costs little).
DEFAULT_TESTS = (
    "tests/test_metrics.py",
    "tests/test_normalisation.py",
    "tests/test_splits.py",
    "tests/test_balance.py",
    "tests/test_augment.py",
    "tests/test_module.py",
    "tests/test_protocol_oracles.py",
    "tests/test_training.py",
)


@dataclass(frozen=True)
class Edit:
    """Replace ``original`` (which must occur exactly once) by ``replacement`` in ``file``
    (relative to ``src/tactile_compliance``)."""

    file: str
    original: str
    replacement: str


@dataclass(frozen=True)
class Mutation:
    name: str
    area: str
    description: str
    edits: tuple[Edit, ...]
    audit: bool = False  # the mutation of the issue-18 audit

    @property
    def files(self) -> list[str]:
        return sorted({e.file for e in self.edits})


def _m(name, area, description, file, original, replacement, audit=False, also=()):
    edits = (Edit(file, original, replacement), *(Edit(*e) for e in also))
    return Mutation(name, area, description, edits, audit)


MUTATIONS: tuple[Mutation, ...] = (
    # ------------------------------------------------------------------ splits
    _m(
        "split-grasp-key-includes-shift",
        "splits",
        "the time-shift (augmentation) index is part of the grasp key (the audit's bug)",
        "data/splits.py",
        'return samples["object"].astype(str) + "/" + samples["grasp"].astype(str)',
        'return (samples["object"].astype(str) + "/" + samples["grasp"].astype(str)'
        ' + "/" + samples["augmentation"].astype(str))',
        audit=True,
    ),
    _m(
        "split-unseen-groups-by-grasp",
        "splits",
        "unseen draws grasps instead of objects (objects leak into test)",
        "data/splits.py",
        'require_columns(samples, ("object",), "the unseen condition")\n'
        '        return samples["object"].astype(str)',
        'require_columns(samples, ("object",), "the unseen condition")\n'
        "        return grasp_keys(samples)",
    ),
    _m(
        "split-grasp-grouping-is-per-sample",
        "splits",
        "grouping=grasp silently splits per sample",
        "data/splits.py",
        'if grouping == "grasp":\n        return grasp_keys(samples)',
        'if grouping == "grasp" and False:\n        return grasp_keys(samples)',
    ),
    _m(
        "split-val-fraction-of-all",
        "splits",
        "validation takes val_fraction of all samples, not of the remaining ones",
        "data/splits.py",
        "val_fraction * sizes[rest].sum()",
        "val_fraction * total",
    ),
    _m(
        "split-ignores-run-seed",
        "splits",
        "split.seed=null uses seed 0 instead of the run seed (no Monte-Carlo resampling)",
        "data/splits.py",
        "seed = sc.seed if sc.seed is not None else cfg.seed",
        "seed = sc.seed if sc.seed is not None else 0",
    ),
    _m(
        "split-ignores-seed",
        "splits",
        "make_split draws every split with seed 0",
        "data/splits.py",
        "rng = np.random.default_rng(seed)\n    total = sizes.sum()",
        "rng = np.random.default_rng(0)\n    total = sizes.sum()",
    ),
    # ------------------------------------------------------------------ balancing
    _m(
        "balance-thresh-from-mean",
        "balance",
        "thresh = t * mean bin count instead of t * largest",
        "data/balance.py",
        "thresh = int(t_balance * counts.max())",
        "thresh = int(t_balance * counts.mean())",
    ),
    _m(
        "balance-bins-on-label-range",
        "balance",
        "bins span the whole label range [0, 1], not the subset's min-max",
        "data/balance.py",
        "lo, hi = float(y.min()), float(y.max())",
        "lo, hi = 0.0, 1.0",
    ),
    _m(
        "balance-copies-pile-on-one-object",
        "balance",
        "the greedy spread never updates an object's count: all copies go to one object",
        "data/balance.py",
        "heapq.heappush(heap, (n_obj + 1, tie, k))",
        "heapq.heappush(heap, (n_obj, tie, k))",
    ),
    _m(
        "balance-validation-flag-ignored",
        "balance",
        "sampling.balance_validation=false still balances validation",
        "data/balance.py",
        'if name == "val" and not balance_validation:',
        "if False:",
    ),
    _m(
        "balance-not-applied-in-training",
        "balance",
        "train() ignores sampling.strategy=balanced",
        "training/train.py",
        'if cfg.sampling.strategy == "balanced":',
        'if cfg.sampling.strategy == "balanced" and False:',
    ),
    # ------------------------------------------------------------------ normalisation
    _m(
        "norm-label-divides-by-max",
        "normalisation",
        "label y = (log10 E - a) / b instead of / (b - a)",
        "data/normalisation.py",
        "y = (_log10(x) - c.label_log10_min) / c.label_log10_span",
        "y = (_log10(x) - c.label_log10_min) / c.label_log10_max",
    ),
    _m(
        "norm-estimates-not-clamped",
        "normalisation",
        "analytical estimates are not clamped to [1e2, 1e14] Pa before log10",
        "data/normalisation.py",
        "clamped = _torch().clamp(x, lo, hi) if _is_tensor(x) else np.clip(x, lo, hi)",
        "clamped = x",
    ),
    _m(
        "norm-image-multiplies-by-std",
        "normalisation",
        "images (x - mean) * std instead of / std",
        "data/normalisation.py",
        "out /= std",
        "out *= std",
    ),
    _m(
        "forward-force-width-swapped",
        "normalisation",
        "force and width swapped on the way into the model (the published code's bug)",
        "runs/forward.py",
        "scalars = {name: batch[name] for name in strategy.scalar_names}",
        'scalars = {name: batch[{"force": "width", "width": "force"}.get(name, name)]'
        " for name in strategy.scalar_names}",
    ),
    # ------------------------------------------------------------------ metrics
    _m(
        "metric-accuracy-excludes-one-decade",
        "metrics",
        "log10 accuracy counts |d| < 1 instead of |d| <= 1",
        "runs/metrics.py",
        "return float(np.mean(d <= tolerance_decades + _TOL_DECADES))",
        "return float(np.mean(d < tolerance_decades))",
    ),
    _m(
        "metric-nmse-is-rmse",
        "metrics",
        "N-MSE returns a root mean square",
        "runs/metrics.py",
        "return float(np.mean((normalise_modulus(p, c) - normalise_modulus(t, c)) ** 2))",
        "return float(np.sqrt(np.mean((normalise_modulus(p, c) - normalise_modulus(t, c)) ** 2)))",
    ),
    _m(
        "metric-mae-is-rmse",
        "metrics",
        "mae_decades returns an RMSE (a mislabelled metric)",
        "runs/metrics.py",
        "return float(np.mean(np.abs(_log_error(true_pa, pred_pa))))",
        "return float(np.sqrt(np.mean(_log_error(true_pa, pred_pa) ** 2)))",
    ),
    _m(
        "metric-median-reference-from-test",
        "metrics",
        "the median reference predictor uses the test set's median",
        "runs/metrics.py",
        'median = float(np.median(train_samples["modulus_pa"].to_numpy(dtype=float)))',
        'median = float(np.median(test_samples["modulus_pa"].to_numpy(dtype=float)))',
    ),
    _m(
        "metric-val-nmse-mean-of-batch-means",
        "metrics",
        "validation N-MSE is a mean of batch means (wrong when the last batch is short)",
        "training/module.py",
        "nmse = torch.cat(self._val_squared_errors).mean()",
        "nmse = torch.stack([e.mean() for e in self._val_squared_errors]).mean()",
    ),
    # ------------------------------------------------------------------ best-epoch restore
    _m(
        "restore-tests-last-epoch",
        "restore",
        "the test split is scored with the last epoch's weights",
        "training/train.py",
        "best_model = load_checkpoint(run_dir / BEST_FILE, device=device).model",
        "best_model = model",
    ),
    _m(
        "restore-best-tracks-last",
        "restore",
        "the best-checkpoint callback keeps every epoch (best = last)",
        "training/resume.py",
        "if score < self.best:",
        "if True:",
    ),
    _m(
        "checkpoint-records-wrong-inputs",
        "restore",
        "the checkpoint records inputs=ALL whatever the model's strategy",
        "runs/run_inputs.py",
        '"inputs": self.inputs.value,',
        '"inputs": "ALL",',
    ),
    # ------------------------------------------------------------------ augmentation
    _m(
        "augment-validation-augmented",
        "augmentation",
        "validation batches are augmented (both gates removed: module and eval mode)",
        "training/module.py",
        "self.augmentation if augment else None,",
        "self.augmentation,",
        also=(
            (
                "data/augment.py",
                "if not self.training or self.probability == 0.0 or frames.shape[0] == 0:",
                "if self.probability == 0.0 or frames.shape[0] == 0:",
            ),
        ),
    ),
    _m(
        "augment-training-never-augmented",
        "augmentation",
        "training batches are never augmented",
        "training/module.py",
        "prediction = self._predict(batch, augment=True).float()",
        "prediction = self._predict(batch, augment=False).float()",
    ),
    _m(
        "augment-frames-differ",
        "augmentation",
        "flips and colour jitter drawn independently per frame",
        "data/augment.py",
        'kaug.VideoSequential(*augmentations, data_format="BTCHW", same_on_frame=True)',
        'kaug.VideoSequential(*augmentations, data_format="BTCHW", same_on_frame=False)',
    ),
)


# ============================================================================ helpers
def check_mutations(src_root: Path, mutations: tuple[Mutation, ...]) -> None:
    """Every snippet occurs exactly once; raise (listing all problems) otherwise."""
    problems = []
    names = [m.name for m in mutations]
    if len(set(names)) != len(names):
        problems.append("duplicate mutation names")
    for mutation in mutations:
        for edit in mutation.edits:
            path = src_root / PACKAGE / edit.file
            if not path.is_file():
                problems.append(f"{mutation.name}: {path} does not exist")
                continue
            count = path.read_text(encoding="utf-8").count(edit.original)
            if count != 1:
                problems.append(
                    f"{mutation.name}: the snippet occurs {count} times in {edit.file} "
                    f"(expected once; the source changed?):\n    {edit.original!r}"
                )
    if problems:
        raise SystemExit("mutations do not match the source:\n  " + "\n  ".join(problems))


def _ignore(directory: str, names: list[str]) -> set[str]:
    skip = {"__pycache__", ".hypothesis", ".pytest_cache", ".ruff_cache", ".benchmarks"}
    return {n for n in names if n in skip or n.endswith(".pyc")}


def _extract(work: Path, rev: str, folder: str) -> None:
    """``folder`` of git revision ``rev`` into ``work`` (read from the repository only)."""
    archive = subprocess.run(
        ["git", "-C", str(REPO), "archive", "--format=tar", rev, folder],
        check=True,
        capture_output=True,
    ).stdout
    with tarfile.open(fileobj=BytesIO(archive)) as tar:
        if hasattr(tarfile, "data_filter"):  # Python >= 3.11.4 / 3.10.12
            tar.extractall(work, filter="data")
        else:  # pragma: no cover - our own git archive
            tar.extractall(work)


def make_copy(work: Path, src_rev: str | None, tests_rev: str | None) -> None:
    """The sandbox: src/ and tests/ (working tree or a git revision), benchmarks/ and
    pyproject.toml (working tree)."""
    work.mkdir(parents=True)
    for folder, rev in (("src", src_rev), ("tests", tests_rev)):
        if rev:
            _extract(work, rev, folder)
        else:
            shutil.copytree(REPO / folder, work / folder, ignore=_ignore)
    shutil.copytree(REPO / "benchmarks", work / "benchmarks", ignore=_ignore)
    shutil.copy2(REPO / "pyproject.toml", work / "pyproject.toml")


def sandbox_env(work: Path) -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(work / "src")
    # No .pyc files: a mutated file of the same size written within the same second as
    # its original would otherwise be read from a stale cache.
    env["PYTHONDONTWRITEBYTECODE"] = "1"
    env.pop("PYTEST_ADDOPTS", None)
    return env


def check_import(work: Path, module_file: str, needle: str | None) -> None:
    """In a fresh interpreter with the sandbox's environment: the package and the mutated
    module come from the copy, and the module's source holds ``needle``."""
    module = f"{PACKAGE}." + module_file.removesuffix(".py").replace("/", ".")
    code = (
        "import importlib, inspect, json, sys\n"
        f"import {PACKAGE} as p\n"
        f"m = importlib.import_module({module!r})\n"
        "print(json.dumps([p.__file__, m.__file__, inspect.getsource(m)]))\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code],
        cwd=work,
        env=sandbox_env(work),
        capture_output=True,
        text=True,
        check=False,
    )
    if out.returncode != 0:
        raise SystemExit(f"importing {module} from the sandbox failed:\n{out.stderr[-2000:]}")
    package_file, file, source = json.loads(out.stdout.strip().splitlines()[-1])
    root = (work / "src").resolve()
    for path in (package_file, file):
        if not Path(path).resolve().is_relative_to(root):
            raise SystemExit(f"{path} is imported instead of the sandbox copy under {root}")
    if needle is not None and needle not in source:
        raise SystemExit(f"the mutation is not in the imported {module} ({file})")


@dataclass
class Outcome:
    mutation: str
    status: str  # caught | survived | error | timeout | baseline
    failed: str = ""
    seconds: float = 0.0
    area: str = ""
    audit: bool = False
    description: str = ""
    tail: list[str] = field(default_factory=list)


_FAILED = re.compile(r"^(FAILED|ERROR) (\S+)")


def run_tests(work: Path, tests: list[str], timeout: float, stop_first: bool) -> Outcome:
    command = [
        sys.executable,
        "-m",
        "pytest",
        *tests,
        "-q",
        "-p",
        "no:cacheprovider",
        "--no-header",
        "-rfE",
        *(["-x"] if stop_first else []),
    ]
    start = time.perf_counter()
    try:
        proc = subprocess.run(
            command,
            cwd=work,
            env=sandbox_env(work),
            capture_output=True,
            text=True,
            timeout=timeout,
            check=False,
        )
    except subprocess.TimeoutExpired:
        return Outcome("", "timeout", f"> {timeout:.0f} s", time.perf_counter() - start)
    seconds = time.perf_counter() - start
    lines = (proc.stdout + proc.stderr).splitlines()
    failed = [m.group(2) for line in lines if (m := _FAILED.match(line))]
    if proc.returncode == 0:
        return Outcome("", "survived", "", seconds, tail=lines[-3:])
    if proc.returncode == 1 and failed:
        return Outcome("", "caught", failed[0], seconds, tail=lines[-3:])
    return Outcome("", "error", f"pytest exit {proc.returncode}", seconds, tail=lines[-25:])


def apply(work: Path, mutation: Mutation) -> dict[Path, str]:
    """Apply a mutation in the sandbox; returns the original texts to restore."""
    saved: dict[Path, str] = {}
    for edit in mutation.edits:
        path = work / "src" / PACKAGE / edit.file
        if path not in saved:
            saved[path] = path.read_text(encoding="utf-8")
        current = path.read_text(encoding="utf-8")
        if current.count(edit.original) != 1:
            restore(saved)
            raise SystemExit(
                f"{mutation.name}: snippet not found once in the sandbox's {edit.file}"
            )
        path.write_text(current.replace(edit.original, edit.replacement), encoding="utf-8")
    return saved


def restore(saved: dict[Path, str]) -> None:
    for path, text in saved.items():
        path.write_text(text, encoding="utf-8")


def markdown_table(outcomes: list[Outcome]) -> str:
    rows = [
        "| # | mutation | area | what it breaks | result | first failing test | s |",
        "|---|----------|------|----------------|--------|--------------------|---|",
    ]
    for i, o in enumerate(outcomes, 1):
        name = f"**{o.mutation}** (audit)" if o.audit else o.mutation
        description = o.description.replace("|", "\\|")
        rows.append(
            f"| {i} | {name} | {o.area} | {description} | {o.status} | "
            f"{o.failed.replace('|', '/') if o.failed else '–'} | {o.seconds:.0f} |"
        )
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tests", nargs="+", default=list(DEFAULT_TESTS), help="test files")
    parser.add_argument("--only", nargs="+", default=None, help="mutation names to run")
    parser.add_argument("--list", action="store_true", help="list the mutations and exit")
    parser.add_argument("--src-rev", default=None, help="take src/ from this git revision")
    parser.add_argument("--tests-rev", default=None, help="take tests/ from this git revision")
    parser.add_argument("--timeout", type=float, default=1800, help="seconds per test run")
    parser.add_argument("--all-tests", action="store_true", help="run every test (no -x)")
    parser.add_argument("--markdown", type=Path, default=None, help="also write the table here")
    parser.add_argument("--json", type=Path, default=None, help="also write the outcomes here")
    parser.add_argument("--keep", action="store_true", help="keep the sandbox directory")
    args = parser.parse_args(argv)

    mutations = MUTATIONS
    if args.only:
        unknown = set(args.only) - {m.name for m in MUTATIONS}
        if unknown:
            parser.error(f"unknown mutation(s): {sorted(unknown)}")
        mutations = tuple(m for m in MUTATIONS if m.name in args.only)
    if args.list:
        for m in mutations:
            print(f"{m.name:40s} {m.area:14s} {', '.join(m.files):28s} {m.description}")
        return 0
    sandbox = Path(tempfile.mkdtemp(prefix="mutation-score-"))
    work = sandbox / "repo"
    try:
        make_copy(work, args.src_rev, args.tests_rev)
        missing = [test for test in args.tests if not (work / test).is_file()]
        if missing:
            parser.error(f"no test file(s) {missing} in the sandbox's tests/")
        check_mutations(work / "src", mutations)
        check_import(work, "data/splits.py", None)
        source = f"git revision {args.src_rev}" if args.src_rev else "the working tree"
        tests_from = f"git revision {args.tests_rev}" if args.tests_rev else "the working tree"
        print(
            f"sandbox {work} (src/ from {source}, tests/ from {tests_from}); "
            f"tests: {' '.join(args.tests)}",
            flush=True,
        )
        baseline = run_tests(work, args.tests, args.timeout, stop_first=False)
        print(f"baseline (unmutated): {baseline.status} in {baseline.seconds:.0f} s", flush=True)
        if baseline.status != "survived":
            print("\n".join(baseline.tail), file=sys.stderr)
            print("the unmutated tests must pass first", file=sys.stderr)
            return 2
        outcomes = []
        for mutation in mutations:
            saved = apply(work, mutation)
            try:
                for edit in mutation.edits:
                    check_import(work, edit.file, edit.replacement)
                outcome = run_tests(work, args.tests, args.timeout, not args.all_tests)
            finally:
                restore(saved)
            outcome.mutation, outcome.area = mutation.name, mutation.area
            outcome.audit, outcome.description = mutation.audit, mutation.description
            outcomes.append(outcome)
            print(
                f"{mutation.name:40s} {outcome.status:9s} {outcome.seconds:6.0f} s "
                f"{outcome.failed}",
                flush=True,
            )
            if outcome.status == "error":
                print("    " + "\n    ".join(outcome.tail), flush=True)
        caught = sum(o.status in ("caught", "timeout") for o in outcomes)
        audit = [o for o in outcomes if o.audit]
        summary = (
            f"caught {caught} of {len(outcomes)} mutations"
            + (f"; the audit's mutation: {audit[0].status}" if audit else "")
            + f"; baseline {baseline.seconds:.0f} s"
        )
        table = markdown_table(outcomes)
        print("\n" + table + "\n\n" + summary)
        machine = f"{platform.node()} ({platform.machine()}, {os.cpu_count()} CPUs)"
        header = (
            f"Command: `python benchmarks/mutation_score.py {' '.join(argv or sys.argv[1:])}`  \n"
            f"Date: {datetime.now(timezone.utc):%Y-%m-%d %H:%M} UTC; machine: {machine}; "
            f"Python {platform.python_version()}; src/ from {source}, tests/ from {tests_from}\n\n"
        )
        if args.markdown:
            args.markdown.write_text(header + table + "\n\n" + summary + "\n", encoding="utf-8")
        if args.json:
            args.json.write_text(
                json.dumps([o.__dict__ for o in outcomes], indent=1) + "\n", encoding="utf-8"
            )
        return 0
    finally:
        if args.keep:
            print(f"sandbox kept: {sandbox}")
        else:
            shutil.rmtree(sandbox, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
