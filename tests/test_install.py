"""What `pip install -e .` asks for: a torch range that keeps a torch the user already has
(docs/install.md, "Which torch"), and every module the cli imports declared."""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest
import torch
from packaging.requirements import Requirement
from packaging.version import Version

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    tomllib = pytest.importorskip("tomli")

REPO = Path(__file__).resolve().parents[1]
PROJECT = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))["project"]


def _requirement(name: str) -> Requirement:
    found = [Requirement(r) for r in PROJECT["dependencies"] if Requirement(r).name == name]
    assert found, f"pyproject.toml does not declare {name}"
    return found[0]


@pytest.mark.parametrize(
    "version",
    [
        "2.5.0a0+872d972e41.nv24.08",  # a Jetson build of 2.5
        "2.5.1",
        "2.12.0+cu126",
        "2.13.0",  # what CI installs
        "2.13.0+cpu",
        "2.14.0",
    ],
)
def test_the_torch_requirement_keeps_a_torch_that_has_what_the_code_uses(version: str) -> None:
    assert _requirement("torch").specifier.contains(Version(version), prereleases=True)


@pytest.mark.parametrize("version", ["2.4.1", "3.0.0"])
def test_the_torch_requirement_excludes_a_torch_without_it(version: str) -> None:
    # 2.4 has no torch.onnx.export(dynamo=...); 3.0 is a major release nobody tested.
    assert not _requirement("torch").specifier.contains(Version(version), prereleases=True)


def test_the_installed_torch_satisfies_the_requirement() -> None:
    assert _requirement("torch").specifier.contains(Version(torch.__version__), prereleases=True)


def test_the_apis_behind_the_lower_bound_exist() -> None:
    """The reasons pyproject.toml gives for torch>=2.5, checked on the installed torch."""
    import inspect

    assert callable(torch.get_autocast_dtype)
    assert torch.is_autocast_enabled("cpu") is False
    assert "dynamo" in inspect.signature(torch.onnx.export).parameters


def _top_level_imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module.split(".")[0])
    return names


def test_every_third_party_module_of_the_cli_is_declared() -> None:
    declared = {Requirement(r).name.replace("-", "_") for r in PROJECT["dependencies"]}
    cli = REPO / "src" / "tactile_compliance" / "cli"
    third_party = set().union(*(_top_level_imports(path) for path in cli.glob("*.py")))
    third_party -= {*sys.stdlib_module_names, "tactile_compliance", "__future__"}
    assert third_party <= declared, f"the cli imports undeclared {third_party - declared}"
