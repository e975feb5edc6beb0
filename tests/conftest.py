"""Shared pytest fixtures."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

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
