"""Shared pytest fixtures."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

# The default run spreads test files over pytest-xdist workers, one per core (addopts in
# pyproject.toml). Each worker, and every process a test starts, then computes on one
# thread: torch's default of a thread per core would put two threads on each core, and
# OpenMP threads spin while they wait. Set before any test module imports torch.
if os.environ.get("PYTEST_XDIST_WORKER"):
    os.environ.setdefault("OMP_NUM_THREADS", "1")

REPO_ROOT = Path(__file__).resolve().parents[1]
# Research scripts in benchmarks/ (not part of the package) are importable by the tests.
sys.path.insert(0, str(REPO_ROOT / "benchmarks"))
# `shared/` lives next to the checkout (../shared); it is never copied into the repository.
REFERENCE_DATA_DIR = REPO_ROOT.parent / "shared" / "reference-data"


@pytest.fixture(scope="session")
def reference_data_dir() -> Path:
    """The real reference files (object table, sensor background), or skip when absent."""
    if not REFERENCE_DATA_DIR.is_dir():
        pytest.skip("../shared/reference-data is not present on this machine")
    return REFERENCE_DATA_DIR


@pytest.fixture(scope="session")
def object_table_csv(reference_data_dir: Path) -> Path:
    """The real object table `dataset_objects_and_compliance.csv` (skip when absent)."""
    path = reference_data_dir / "dataset_objects_and_compliance.csv"
    if not path.is_file():
        pytest.skip(f"{path} is not present")
    return path


# pytest-xdist (`--dist loadfile`) hands whole files to the workers in collection order,
# so the run ends when the last file to start ends. The heaviest files start first
# (seconds of their tests on the 2-core VM at one thread per worker, 2026-12-02, from
# `--junitxml`; every other file takes under 41 s).
HEAVIEST_FILES_FIRST = (
    "test_training.py",  # 132 s
    "test_experiment.py",  # 130 s
    "test_hpo.py",  # 97 s
    "test_resume.py",  # 74 s
    "test_demo.py",  # 74 s
    "test_checkpoint.py",  # 53 s
    "test_models.py",  # 49 s
    "test_sim2real.py",  # 46 s
    "test_rig_calibration.py",  # 45 s
)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Put the tests of :data:`HEAVIEST_FILES_FIRST` first, in that order (a stable sort:
    within a file, and among the other files, the order stays as collected)."""
    rank = {name: k for k, name in enumerate(HEAVIEST_FILES_FIRST)}
    items.sort(key=lambda item: rank.get(item.path.name, len(rank)))
