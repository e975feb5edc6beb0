"""The docs describe the system as it is: shipped configs, documented commands, and code
blocks that run.

* The reference config in docs/protocol.md is the shipped default preset, key for key; the
  experiment-file example in docs/experiments.md is the shipped table1 grid.
* Every `tactile-compliance ...` command line in README.md and docs/*.md names an existing
  command, and every `--option` it uses exists on that command.
* Every fenced block says what it is (an info string: ``python``, ``bash``, ``text``, ...).
* Every ``python`` and shell block runs here, on tiny data, or is marked illustrative by an
  ``<!-- illustrative: REASON -->`` line right before its fence (docs/testing.md). A
  runnable block runs in a sandbox directory whose names are the docs' own (``stores/ym``,
  ``runs/RUN``, ``STORE``, ...: tiny stand-ins); the Python blocks of one page share one
  namespace, in order, like a notebook, that starts with one grasp's ``frames``, ``force``,
  ``width`` and ``estimates``. An illustrative Python block still compiles and its imports
  still run, so a documented name that disappears fails here too.
* A runnable block reads only what it or the sandbox made: it names no path outside its
  working directory (``/tmp/...``, ``~``, ``$HOME``, ``..``), and it runs with a fresh
  ``HOME`` and ``TMPDIR``, so a block that passes only where someone ran earlier steps by
  hand fails here.
"""

from __future__ import annotations

import ast
import os
import re
import shlex
import tempfile
from dataclasses import dataclass
from pathlib import Path

import pytest
import typer.main
import yaml
from typer.testing import CliRunner

from tactile_compliance.cli import app
from toy_store import make_toy_store, tiny_run_config

try:  # typer vendors its own click since 0.20; its commands use that one
    from typer import _click as click
    from typer._click.exceptions import UsageError
except ImportError:  # pragma: no cover
    import click  # type: ignore[no-redef]
    from click.exceptions import UsageError  # type: ignore[no-redef]

REPO = Path(__file__).resolve().parents[1]
DOCS = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
SHELL = ("bash", "sh", "shell", "console")
#: The line right before a fence that marks its block illustrative (docs/testing.md).
ILLUSTRATIVE = re.compile(r"^<!--\s*illustrative:\s*(?P<reason>\S.*?)\s*-->$")


@dataclass(frozen=True)
class Block:
    """A fenced code block of a doc page."""

    doc: str
    line: int  # of the opening fence, 1-based
    language: str
    body: str
    illustrative: str | None  # the reason, when marked

    @property
    def id(self) -> str:
        return f"{self.doc}:{self.line}"


def _parse_blocks(text: str, doc: str = "") -> list[Block]:
    """The fenced code blocks of a Markdown text, in order."""
    blocks: list[Block] = []
    lines = text.splitlines()
    start, language = None, ""
    for number, line in enumerate(lines):
        if not line.startswith("```"):
            continue
        if start is None:
            start, language = number, line[3:].strip().split(" ")[0]
            continue
        before = lines[start - 1].strip() if start else ""
        marked = ILLUSTRATIVE.match(before)
        body = "\n".join(lines[start + 1 : number]) + "\n"
        blocks.append(Block(doc, start + 1, language, body, marked["reason"] if marked else None))
        start = None
    return blocks


def _blocks(doc: Path) -> list[Block]:
    return _parse_blocks(doc.read_text(encoding="utf-8"), doc.relative_to(REPO).as_posix())


def _yaml_blocks(text: str) -> list[str]:
    return [block.body for block in _parse_blocks(text) if block.language == "yaml"]


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
        for block in _blocks(doc):
            if block.language not in SHELL:
                continue
            joined = re.sub(r"\\\n\s*", " ", block.body)  # continuation lines
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


def test_the_experiment_file_example_is_the_shipped_table1_grid() -> None:
    text = (REPO / "docs" / "experiments.md").read_text(encoding="utf-8")
    example = text[text.index("## Experiment files") :]
    documented = yaml.safe_load(_yaml_blocks(example)[0])
    shipped_path = REPO / "src" / "tactile_compliance" / "configs" / "experiments" / "table1.yaml"
    shipped = yaml.safe_load(shipped_path.read_text(encoding="utf-8"))
    # rules, include and quick are the page's own examples of the format.
    for key in ("description", "config", "set", "grid", "seeds", "paper_settings"):
        assert documented[key] == shipped[key], key


# ============================================================================ blocks that run
BLOCKS = [block for doc in DOCS for block in _blocks(doc)]
PYTHON = [b for b in BLOCKS if b.language == "python"]
SHELL_BLOCKS = [b for b in BLOCKS if b.language in SHELL]


def test_every_block_says_what_it_is_and_every_marker_marks_a_block() -> None:
    assert len(PYTHON) > 10 and len(SHELL_BLOCKS) > 10  # the extraction itself works
    untagged = [b.id for b in BLOCKS if not b.language]
    assert not untagged, f"fenced blocks without an info string (python, bash, text...): {untagged}"
    for doc in DOCS:
        lines = doc.read_text(encoding="utf-8").splitlines()
        for number, line in enumerate(lines):
            if "illustrative" in line and line.lstrip().startswith("<!--"):
                name = f"{doc.relative_to(REPO).as_posix()}:{number + 1}"
                assert ILLUSTRATIVE.match(line.strip()), f"{name}: give a reason: {line}"
                following = lines[number + 1] if number + 1 < len(lines) else ""
                assert following.startswith("```"), f"{name}: the marker must precede a fence"


@pytest.mark.parametrize("block", PYTHON, ids=[b.id for b in PYTHON])
def test_every_python_block_compiles_and_its_imports_exist(block: Block) -> None:
    tree = ast.parse(block.body, filename=block.id)
    imports = [node for node in tree.body if isinstance(node, ast.Import | ast.ImportFrom)]
    exec(compile(ast.Module(body=imports, type_ignores=[]), block.id, "exec"), {})


def _grasp(store) -> dict:
    """One grasp of a store as a user holds it: the inputs the docs' examples pass."""
    return {
        "frames": store.load_frames([0])[0],  # (3, H, W, 3) float32 difference images
        "force": store.forces_n()[0],  # (3,) N
        "width": store.widths_m()[0],  # (3,) m
        "estimates": store.estimates_pa()[0],  # (2,) Pa
    }


def _fresh_home_and_tmp(monkeypatch: pytest.MonkeyPatch, root: Path) -> None:
    """Point HOME and TMPDIR (and Python's cached temporary directory) at new empty
    folders under ``root``: nothing a block reads may come from an earlier session."""
    for name in ("HOME", "TMPDIR"):
        folder = root / f".{name.lower()}"
        folder.mkdir()
        monkeypatch.setenv(name, str(folder))
    for name in ("XDG_CACHE_HOME", "XDG_CONFIG_HOME", "XDG_DATA_HOME"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr(tempfile, "tempdir", None)  # gettempdir() re-reads TMPDIR


@pytest.fixture(scope="module")
def sandbox(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The docs' names, standing for tiny data: stores (one toy store), trained runs (one
    epoch each: Top10NN ALL as ``runs/RUN``, also what the report's Fig. 5 needs, and two
    Top10NN ImageFW seeds for the ensemble example), a config file and a results store of
    those runs."""
    root = tmp_path_factory.mktemp("docs-sandbox")
    with pytest.MonkeyPatch.context() as monkeypatch:
        _fresh_home_and_tmp(monkeypatch, root)
        _build_sandbox(root)
    return root


def _build_sandbox(root: Path) -> None:
    from tactile_compliance.config import load_config, save_config
    from tactile_compliance.runs.results import ResultsStore, result_row
    from tactile_compliance.training.train import train

    store = make_toy_store(root / "data" / "toy", n_objects=8, grasps=2, size=(72, 72))
    (root / "stores").mkdir()
    for name in ("ym", "quick", "synthetic"):
        (root / "stores" / name).symlink_to(store.path)
    (root / "STORE").symlink_to(store.path)
    runs, results = root / "runs", ResultsStore(root / "results")
    for inputs, seed in (("ALL", 0), ("ImageFW", 0), ("ImageFW", 1)):
        extra = ["data.image_size=[72,72]", "training.max_epochs=1", f"inputs={inputs}"]
        cfg = tiny_run_config(store.path, runs, "top10nn", [*extra, f"seed={seed}"])
        result = train(cfg, progress=False)
        results.record(result_row(cfg, result, preset="docs"))
        if inputs == "ALL":
            (runs / "RUN").symlink_to(result["run_dir"])
    save_config(load_config("default"), runs / "my.yaml")


@pytest.fixture
def workdir(sandbox: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A fresh working directory with the sandbox's names (what a block writes stays here,
    but under runs/ and results/, which are shared), and a fresh HOME and TMPDIR."""
    for entry in sandbox.iterdir():
        if entry.name not in ("data", ".home", ".tmpdir"):
            (tmp_path / entry.name).symlink_to(entry)
    _fresh_home_and_tmp(monkeypatch, tmp_path)
    monkeypatch.chdir(tmp_path)
    return tmp_path


def test_the_blocks_run_with_a_fresh_home_and_tmpdir(workdir: Path) -> None:
    for folder in (Path(os.environ["HOME"]), Path(os.environ["TMPDIR"])):
        assert folder.is_relative_to(workdir) and not any(folder.iterdir())
    assert Path(tempfile.gettempdir()).is_relative_to(workdir)
    assert Path("~").expanduser().is_relative_to(workdir)


def _pages(blocks: list[Block]) -> dict[str, list[Block]]:
    pages: dict[str, list[Block]] = {}
    for block in blocks:
        if block.illustrative is None:
            pages.setdefault(block.doc, []).append(block)
    return pages


PYTHON_PAGES = _pages(PYTHON)


@pytest.mark.parametrize("doc", sorted(PYTHON_PAGES))
def test_the_python_blocks_of_each_page_run(doc: str, workdir: Path, sandbox: Path) -> None:
    from tactile_compliance.data.store import GraspStore
    from tactile_compliance.models import registry

    namespace = {"__name__": "__docs__", **_grasp(GraspStore.open(sandbox / "stores" / "ym"))}
    registry.discover_models()  # the built-in models are in the snapshot
    models = dict(registry._REGISTRY)  # a page may register an example model
    try:
        for block in PYTHON_PAGES[doc]:
            try:
                exec(compile(block.body, block.id, "exec"), namespace)
            except Exception as err:
                pytest.fail(f"{block.id} (python) fails: {type(err).__name__}: {err}")
    finally:
        registry._REGISTRY.clear()
        registry._REGISTRY.update(models)


def _shell_commands(block: Block) -> list[str]:
    """The commands of a shell block (continuations joined, comments dropped)."""
    joined = re.sub(r"\\\n\s*", " ", block.body)
    commands = []
    for line in joined.splitlines():
        line = line.split("#", 1)[0].strip() if not line.lstrip().startswith("#") else ""
        commands.extend(part.strip() for part in re.split(r"&&|;", line) if part.strip())
    return commands


RUNNABLE_SHELL_BLOCKS = [b for b in SHELL_BLOCKS if b.illustrative is None]

#: The start of a path that only something outside a block's working directory can have
#: made: absolute, in a home directory, in TMPDIR, or above the working directory.
OUTSIDE = re.compile(r"^(/|~|\$\{?HOME\b|\$\{?TMPDIR\b|\.\.(/|$))")


def _outside_paths(block: Block) -> list[str]:
    """The words of a block (shell words, ``--option=value`` and ``key=value`` values, Python
    string constants) that name a path outside the block's working directory."""
    if block.language == "python":
        tree = ast.parse(block.body, filename=block.id)
        words = [n.value for n in ast.walk(tree) if isinstance(n, ast.Constant)]
        words = [word for word in words if isinstance(word, str)]
    else:
        words = [word for command in _shell_commands(block) for word in shlex.split(command)]
    values = [part for word in words for part in [word, *word.split("=")[1:]]]
    return [value for value in values if OUTSIDE.match(value)]


def test_the_outside_path_check_finds_outside_paths() -> None:
    bash = "```bash\ntactile-compliance info /tmp/shore/store\n"
    bash += "tactile-compliance train --set data.store=~/stores/ym --out=../runs\n```\n"
    python = '```python\nopen("/tmp/x.csv")\nPath("stores/ym")\n```\n'
    found = [_outside_paths(block) for block in _parse_blocks(bash + python)]
    assert found == [["/tmp/shore/store", "~/stores/ym", "../runs"], ["/tmp/x.csv"]]


RUNNABLE = [b for b in [*SHELL_BLOCKS, *PYTHON] if b.illustrative is None]


@pytest.mark.parametrize("block", RUNNABLE, ids=[b.id for b in RUNNABLE])
def test_no_runnable_block_reads_outside_its_directory(block: Block) -> None:
    outside = _outside_paths(block)
    assert not outside, (
        f"{block.id}: names {outside}, which exist only where someone made them by hand; "
        "make them in the block, under its working directory, or mark the block "
        "<!-- illustrative: REASON -->"
    )


@pytest.mark.parametrize("block", RUNNABLE_SHELL_BLOCKS, ids=[b.id for b in RUNNABLE_SHELL_BLOCKS])
def test_the_runnable_shell_blocks_run(block: Block, workdir: Path) -> None:
    commands = _shell_commands(block)
    assert commands, f"{block.id}: an empty shell block"
    for command in commands:
        words = shlex.split(command)
        assert words[0] == "tactile-compliance", (
            f"{block.id}: `{command}` is not a tactile-compliance command; run it here or "
            "mark the block <!-- illustrative: REASON -->"
        )
        result = CliRunner().invoke(app, words[1:])
        assert result.exit_code == 0, f"{block.id}: `{command}` failed:\n{result.output[-3000:]}"


# ============================================================================ the sensor table
def test_the_sensor_table_in_the_docs_is_the_code_table() -> None:
    """docs/inference.md's table of source specs has one row per entry of
    ``acquisition.sensors.SENSORS``, in its order, with its class, liveness and channels."""
    from tactile_compliance.acquisition.sensors import SENSORS

    text = (REPO / "docs" / "inference.md").read_text(encoding="utf-8")
    header = "| spec | source | live | channels |"
    rows = text[text.index(header) :].split("\n\n")[0].splitlines()[2:]
    cells = [[cell.strip() for cell in row.strip("|").split(" | ")] for row in rows]
    assert [re.match(r"`(\w+):", spec).group(1) for spec, *_ in cells] == [
        kind.name for kind in SENSORS
    ]
    for (_, source, live, channels, _), kind in zip(cells, SENSORS, strict=True):
        assert f"`{kind.source_class.__name__}`" in source, (kind.name, source)
        assert (live, channels) == (kind.live, kind.channel_order), kind.name
