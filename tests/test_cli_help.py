"""The command line's help and usage errors: every `--help` of every command and
sub-command reads as a user needs it (no `<bool>` on flags, no `<list[...]>`, no
`{store}` placeholders, every choice listed), choices are checked by the parser, a usage
error is one line, and the command starts as `tactile-compliance` and as
`python -m tactile_compliance`."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import typing
from pathlib import Path

import pytest
import typer.main
from typer.testing import CliRunner

from tactile_compliance.cli import app, options

REPO = Path(__file__).resolve().parents[1]
#: Wide enough that rich wraps no choice list.
WIDE = {"COLUMNS": "250", "TERMINAL_WIDTH": "250"}
runner = CliRunner()


def _commands() -> list[tuple[list[str], typing.Any]]:
    """(path, click command) of the root, every group and every command."""
    found = []

    def walk(path: list[str], command: typing.Any) -> None:
        found.append((path, command))
        for name in getattr(command, "commands", {}):
            walk([*path, name], command.commands[name])

    walk([], typer.main.get_command(app))
    return found


COMMANDS = _commands()


def test_the_walk_finds_every_command() -> None:
    names = {" ".join(path) for path, _ in COMMANDS}
    assert {"", "import", "import burgess", "import yuan", "predict", "tune-balance"} <= names
    assert len(names) >= 22


def _choices(command: typing.Any) -> dict[str, tuple[str, ...]]:
    """Option or argument name -> the choices its annotation allows (a Literal)."""
    callback = getattr(command.callback, "__wrapped__", command.callback)
    if callback is None:
        return {}
    hints = typing.get_type_hints(callback, include_extras=True)
    found = {}
    for name, hint in hints.items():
        if typing.get_origin(hint) is typing.Annotated:
            hint = typing.get_args(hint)[0]
        if typing.get_origin(hint) is typing.Union:  # Optional[Literal[...]]
            hint = next(a for a in typing.get_args(hint) if a is not type(None))
        if typing.get_origin(hint) is typing.Literal:
            found[name] = typing.get_args(hint)
    return found


@pytest.mark.parametrize(
    "path", [p for p, _ in COMMANDS], ids=[" ".join(p) or "(root)" for p, _ in COMMANDS]
)
def test_every_help_shows_values_only_where_an_option_takes_one(path: list[str]) -> None:
    result = runner.invoke(app, [*path, "--help"], env=WIDE)
    assert result.exit_code == 0, result.output
    text = result.output
    assert "Usage:" in text
    assert "<bool>" not in text, "a flag takes no value"
    assert "<list[" not in text, "a repeatable option takes one value per use"
    usage = next(line for line in text.splitlines() if "Usage:" in line)
    assert not re.search(r"\{\w+\}", usage), usage
    command = dict((tuple(p), c) for p, c in COMMANDS)[tuple(path)]
    for name, choices in _choices(command).items():
        assert f"<{'|'.join(choices)}>" in text, f"{' '.join(path)}: {name} lists no choices"


def test_the_choices_are_the_library_vocabularies() -> None:
    """The CLI writes its choices out (so it starts without importing torch); each must be
    the vocabulary of its home in the library."""
    from tactile_compliance.config import SplitConfig
    from tactile_compliance.data import raw_layout
    from tactile_compliance.data.inputs import InputStrategy
    from tactile_compliance.demo import PLANS
    from tactile_compliance.runs.layout import KEEP_CHECKPOINTS
    from tactile_compliance.training.hpo.objectives import OBJECTIVES
    from tactile_compliance.training.pretrain import PRETRAIN_BACKBONES

    def values(literal: typing.Any) -> set[str]:
        return set(typing.get_args(literal))

    assert values(options.Fingers) == values(raw_layout.FingerChoice)
    assert values(options.Condition) == values(SplitConfig.model_fields["condition"].annotation)
    assert values(options.Grouping) == values(SplitConfig.model_fields["grouping"].annotation)
    assert typing.get_args(options.Inputs) == InputStrategy.names()
    assert values(options.Objective) == set(OBJECTIVES)
    assert values(options.KeepCheckpoints) == set(KEEP_CHECKPOINTS)
    assert values(options.Backbone) == set(PRETRAIN_BACKBONES)
    assert values(options.DemoMode) == set(PLANS)
    assert values(options.PickleDtype) == set(raw_layout.ALLOWED_DTYPES)


def test_tune_balance_help_keeps_its_budget_defaults() -> None:
    text = runner.invoke(app, ["tune-balance", "--help"], env=WIDE).output
    assert "10; 50 with --paper-budget" in text and "30; 132 with --paper-budget" in text
    condition = next(line for line in text.splitlines() if "--condition" in line)
    assert "config's" not in condition and "[default: seen]" in condition


def test_the_main_help_shows_the_whole_flow() -> None:
    text = " ".join(runner.invoke(app, ["--help"], env=WIDE).output.split())
    flow = text[text.index("Typical flow") :]
    for command in ("simulate", "import", "split", "train", "experiment", "evaluate", "report"):
        assert f"`{command}`" in flow, command
    for command in ("export", "predict", "calibrate", "live", "record"):
        assert f"`{command}`" in flow, command


def _one_error_line(result: typing.Any) -> str:
    lines = [line for line in result.output.strip().splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), result.output
    return lines[0]


@pytest.mark.parametrize(
    ("args", "cause"),
    [
        (["predict", "run", "store", "--fingers", "markeless"], "'markeless' is not one of"),
        (["import", "burgess", "src", "--out", "s", "--fingers", "left"], "'left' is not one of"),
        (["split", "store", "--out", "s.json", "--condition", "unsen"], "'unsen' is not one of"),
        (["tune", "top10nn", "--inputs", "everything"], "'everything' is not one of"),
        (["experiment", "table1", "--keep-checkpoints", "last"], "'last' is not one of"),
        (["demo", "--mode", "fast"], "'fast' is not one of"),
        (["simulate", "--out", "x", "--kind", "lidar"], "'lidar' is not one of"),
        (["info", "--jsn", "store"], "No such option: --jsn"),
        (["info"], "Missing argument 'STORE'"),
    ],
)
def test_a_usage_error_is_one_line_naming_the_option(args: list[str], cause: str) -> None:
    result = runner.invoke(app, args)
    assert result.exit_code == 2, result.output
    line = _one_error_line(result)
    assert cause in line and "--help" in line, line


def test_the_bare_command_prints_help_and_exits_0() -> None:
    for args in ([], ["import"]):
        result = runner.invoke(app, args)
        assert result.exit_code == 0, result.output
        assert "Usage:" in result.output and "Commands" in result.output


def _subprocess(*args: str) -> subprocess.CompletedProcess[str]:
    env = {**os.environ, **WIDE, "PYTHONPATH": os.pathsep.join([str(REPO / "src"), *sys.path])}
    return subprocess.run(
        [sys.executable, *args], capture_output=True, text=True, env=env, timeout=120, check=False
    )


def test_python_dash_m_runs_the_command() -> None:
    result = _subprocess("-m", "tactile_compliance", "--version")
    assert result.returncode == 0 and result.stdout.startswith("tactile-compliance "), result
    bare = _subprocess("-m", "tactile_compliance")
    assert bare.returncode == 0 and "Usage: tactile-compliance" in bare.stdout, bare
    wrong = _subprocess("-m", "tactile_compliance", "predict", "a", "b", "--fingers", "x")
    assert wrong.returncode == 2 and len(wrong.stderr.strip().splitlines()) == 1, wrong
    assert wrong.stdout == "", wrong


def test_live_takes_its_source_as_an_argument(tmp_path: Path) -> None:
    """`live CHECKPOINT... SOURCE` like `record SOURCE`. The checkpoint is checked first, so
    its error shows how the line parsed."""
    text = runner.invoke(app, ["live", "--help"], env=WIDE).output
    assert "[CHECKPOINTS]... SOURCE" in text and "--source" not in text, text
    missing = tmp_path / "missing.pt"
    readings = ["--readings", str(tmp_path / "r.csv")]
    for args in (
        [str(missing), "video:grasp.avi", *readings],
        [str(missing), *readings, "--", "-odd-name.avi"],
    ):
        result = runner.invoke(app, ["live", *args])
        assert result.exit_code == 2, (args, result.output)
        assert _one_error_line(result) == f"error: {missing}: checkpoint not found", args
    for args, cause in (
        ([str(missing), *readings], "is a model, not a frame source: give CHECKPOINTS..."),
        ([str(missing), "--source", "a"], "No such option: --source"),
    ):
        result = runner.invoke(app, ["live", *args])
        assert result.exit_code == 2, (args, result.output)
        assert cause in _one_error_line(result), (args, result.output)


def test_every_command_has_json_and_presets_prints_it() -> None:
    """docs/cli.md: --json on every command (each prints results)."""
    for path, command in COMMANDS:
        if path and not hasattr(command, "commands"):
            assert "--json" in {o for p in command.params for o in p.opts}, path
    result = runner.invoke(app, ["presets", "--json"])
    assert result.exit_code == 0, result.output
    listed = json.loads(result.stdout)
    assert "table1" in listed["experiments"] and "default" in listed["configs"], listed


def _table_rows() -> dict[str, list[str]]:
    """docs/cli.md's table: command path -> its cells."""
    text = (REPO / "docs" / "cli.md").read_text(encoding="utf-8")
    rows: dict[str, list[str]] = {}
    for line in text.splitlines():
        if not line.startswith("| `"):
            continue
        cells = [cell.strip() for cell in line.strip("|").split("|")]
        rows[re.findall(r"`([a-z0-9 -]+)`", cells[0])[0]] = cells
    return rows


def test_the_docs_table_of_commands_is_the_command_line() -> None:
    rows = _table_rows()
    commands = {" ".join(p): c for p, c in COMMANDS if p and not hasattr(c, "commands")}
    assert set(rows) == set(commands)
    for name, cells in rows.items():
        options = {o for param in commands[name].params for o in param.opts}
        for option in re.findall(r"`(--[a-z-]+)", " ".join(cells[1:])):
            assert option in options, f"docs/cli.md: {name} has no {option}"
        assert cells[4].startswith("yes") == ("--json" in options), f"{name}: --json column"
