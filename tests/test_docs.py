"""The docs describe the system as it is: shipped configs and documented commands.

* The reference config in docs/protocol.md is the shipped default preset, key for key.
* Every `tactile-compliance ...` command line in README.md and docs/*.md names an existing
  command, and every `--option` it uses exists on that command.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest
import typer.main
import yaml

from tactile_compliance.cli import app

try:  # typer vendors its own click since 0.20; its commands use that one
    from typer import _click as click
    from typer._click.exceptions import UsageError
except ImportError:  # pragma: no cover
    import click  # type: ignore[no-redef]
    from click.exceptions import UsageError  # type: ignore[no-redef]

REPO = Path(__file__).resolve().parents[1]
DOCS = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
SHELL = ("bash", "sh", "shell", "console", "")


def _fenced_blocks(text: str, languages: tuple[str, ...]) -> list[str]:
    """The bodies of the fenced code blocks whose language is one of ``languages``."""
    blocks, body, language = [], [], None
    for line in text.splitlines():
        if line.startswith("```"):
            if language is None:
                language = line[3:].strip()
                body = []
            else:
                if language in languages:
                    blocks.append("\n".join(body) + "\n")
                language = None
        elif language is not None:
            body.append(line)
    return blocks


def _yaml_blocks(text: str) -> list[str]:
    return _fenced_blocks(text, ("yaml",))


def test_the_reference_config_in_the_docs_is_the_shipped_default() -> None:
    text = (REPO / "docs" / "protocol.md").read_text(encoding="utf-8")
    reference = text[text.index("### Reference") :]
    documented = yaml.safe_load(_yaml_blocks(reference)[0])
    shipped_path = REPO / "src" / "tactile_compliance" / "configs" / "default.yaml"
    assert documented == yaml.safe_load(shipped_path.read_text(encoding="utf-8"))


def _command_lines() -> list[tuple[str, str]]:
    """(doc name, command line) for every `tactile-compliance` line in a shell block."""
    found = []
    for doc in DOCS:
        for block in _fenced_blocks(doc.read_text(encoding="utf-8"), SHELL):
            joined = re.sub(r"\\\n\s*", " ", block)  # continuation lines
            for line in joined.splitlines():
                line = line.split("  #", 1)[0].strip()
                for part in re.split(r"&&|;", line):
                    part = part.strip()
                    if part.startswith("tactile-compliance "):
                        found.append((doc.name, part))
    return found


COMMAND_LINES = _command_lines()


def test_the_docs_show_command_lines() -> None:
    assert len(COMMAND_LINES) > 20  # the extraction itself works


@pytest.mark.parametrize(
    ("doc", "line"), COMMAND_LINES, ids=[f"{doc}:{line[:60]}" for doc, line in COMMAND_LINES]
)
def test_every_documented_command_and_option_exists(doc: str, line: str) -> None:
    words = shlex.split(line.replace("[", "").replace("]", "").replace("...", ""))[1:]
    command = typer.main.get_command(app)
    path = []
    # Duck-typed: typer's groups need not be click.Group instances of the click in use.
    while hasattr(command, "list_commands") and words and not words[0].startswith("-"):
        sub = command.get_command(click.Context(command), words[0])
        if sub is None:
            break
        command, path = sub, [*path, words.pop(0)]
    assert path, f"{doc}: `{line}` names no command"
    options = {opt for param in command.params for opt in (*param.opts, *param.secondary_opts)}
    options |= {"--help", "--debug", "--version"}
    for word in words:
        if word.startswith("--"):
            name = word.split("=", 1)[0]
            assert name in options, f"{doc}: `{line}`: {' '.join(path)} has no option {name}"
    if "[" in line or "..." in line:  # a synopsis ([--out DIR] ...): illustrative on purpose
        return
    # The whole line parses: the right number of arguments, option values of the right type.
    try:
        command.make_context(" ".join(path), list(words))
    except UsageError as err:
        pytest.fail(f"{doc}: `{line}`: {err.format_message()}")
