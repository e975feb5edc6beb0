"""No command deletes or overwrites a path it did not create (tactile_compliance.outputs).

Every output option of every command is pointed at a directory of a user's files (or at a
user's file, for options that name a file). The command must refuse with one error line
and exit code 2, and leave every byte as it was.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from tactile_compliance.cli import app
from tactile_compliance.outputs import (
    MARKER_NAME,
    OutputExistsError,
    check_format_version,
    check_output_file,
    claim_output_dir,
    commit_path,
    output_kind,
    process_alive,
    process_start,
)

runner = CliRunner()


def _user_dir(path: Path) -> Path:
    """A directory of someone's work, with names our outputs also use."""
    (path / "chapter").mkdir(parents=True)
    (path / "thesis.tex").write_text("\\section{Results}\n")
    (path / "chapter" / "data.csv").write_text("a,b\n1,2\n")
    for name in ("report.md", "config.yaml", "split.json", "metrics.json", ".lock"):
        (path / name).write_text(f"the user's {name}\n")
    (path / ".partial-notes").write_text("a file the generators' clean-up must not touch\n")
    return path


def _snapshot(path: Path) -> dict[str, str]:
    if path.is_file():
        return {path.name: hashlib.sha256(path.read_bytes()).hexdigest()}
    return {
        str(p.relative_to(path)): hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else ""
        for p in sorted(path.rglob("*"))
    }


@pytest.fixture(scope="module")
def toy_store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from toy_store import make_toy_store

    path = tmp_path_factory.mktemp("store") / "store"
    make_toy_store(path, n_objects=4, grasps=2, size=(8, 8))
    return path


def _commands(user: Path, user_file: Path, store: Path) -> dict[str, list[str]]:
    """Every command with an output option, that option pointed at the user's files."""
    return {
        "simulate --out": ["simulate", "--out", str(user), "--objects", "1", "--size", "32x32"],
        "simulate shore-videos --out": [
            "simulate",
            "--out",
            str(user),
            "--kind",
            "shore-videos",
            "--objects",
            "1",
            "--size",
            "32x32",
        ],
        "split --out (a file)": ["split", str(store), "--out", str(user_file)],
        "experiment --out": [
            "experiment",
            "table1",
            "--quick",
            "--store",
            str(store),
            "--out",
            str(user),
        ],
        "experiment --results": [
            "experiment",
            "table1",
            "--quick",
            "--store",
            str(store),
            "--out",
            str(user.parent / "fresh-runs"),
            "--results",
            str(user),
        ],
        "report --out": ["report", str(store), "--out", str(user)],
        # A frame size the model takes: only the output directory is wrong.
        "train --out": [
            "train",
            "--set",
            f"data.store={store}",
            "--size",
            "72x72",
            "--out",
            str(user),
        ],
        "tune --out": [
            "tune",
            "top10nn",
            "--store",
            str(store),
            "--trials",
            "1",
            "--min-epochs",
            "1",
            "--max-epochs",
            "1",
            "--out",
            str(user),
        ],
        "export --onnx (a file)": ["export", str(store / "no-run"), "--onnx", str(user_file)],
        "export --safetensors": ["export", str(store / "no-run"), "--safetensors", str(user)],
        "tune-balance --out": [
            "tune-balance",
            "--store",
            str(store),
            "--models",
            "top10nn",
            "--trials",
            "1",
            "--epochs",
            "1",
            "--out",
            str(user),
        ],
        "demo --out": ["demo", "--out", str(user), "--mode", "ci"],
        "import --report (a file)": [
            "import",
            "burgess",
            str(store),
            "--out",
            str(user.parent / "fresh-store"),
            "--report",
            str(user_file),
        ],
    }


def test_no_command_touches_a_users_files(tmp_path: Path, toy_store: Path) -> None:
    user = _user_dir(tmp_path / "user")
    user_file = tmp_path / "notes.json"
    user_file.write_text('{"mine": true}\n')
    before = _snapshot(user), _snapshot(user_file)
    for label, args in _commands(user, user_file, toy_store).items():
        result = runner.invoke(app, args)
        assert result.exit_code == 2, (label, result.output, result.exception)
        lines = [line for line in result.output.splitlines() if line.strip()]
        assert lines[-1].startswith("error: "), (label, result.output)
        # Refused for the right reason: the path is not this command's output.
        assert "by tactile-compliance" in lines[-1], (label, lines)
        assert (_snapshot(user), _snapshot(user_file)) == before, label
        assert not (user / MARKER_NAME).exists(), label
    assert not (tmp_path / "fresh-store").exists(), "a refused --report must cost no import"


def test_a_claimed_directory_is_reused_by_its_own_kind_only(tmp_path: Path) -> None:
    out = claim_output_dir(tmp_path / "report", "report")
    assert output_kind(out) == "report"
    (out / "report.md").write_text("ours\n")
    assert claim_output_dir(out, "report") == out  # a re-run refreshes its own output
    with pytest.raises(OutputExistsError, match="output of `report`"):
        claim_output_dir(out, "demo")
    empty = tmp_path / "empty"
    empty.mkdir()
    assert output_kind(claim_output_dir(empty, "demo")) == "demo"
    with pytest.raises(OutputExistsError, match="is a file"):
        claim_output_dir(tmp_path / "report" / "report.md", "report")


def test_an_older_output_is_recognised_and_adopted(tmp_path: Path) -> None:
    old = tmp_path / "old-report"
    old.mkdir()
    (old / "report.json").write_text("{}\n")
    claim_output_dir(old, "report", recognise=lambda p: (p / "report.json").is_file())
    assert output_kind(old) == "report"


def test_a_file_is_replaced_only_when_it_is_ours(tmp_path: Path) -> None:
    ours, theirs = tmp_path / "ours.json", tmp_path / "theirs.json"
    ours.write_text('{"format": "mine"}\n')
    theirs.write_text("not json at all\n")

    def recognise(path: Path) -> bool:
        import json

        return json.loads(path.read_text())["format"] == "mine"

    assert check_output_file(ours, "split", recognise) == ours
    assert check_output_file(tmp_path / "new.json", "split", recognise) == tmp_path / "new.json"
    with pytest.raises(OutputExistsError, match="not a split"):
        check_output_file(theirs, "split", recognise)
    with pytest.raises(OutputExistsError, match="is a directory"):
        check_output_file(tmp_path, "split", recognise)


@pytest.mark.parametrize("exchange", ["renameat2", "two renames"])
def test_exchange_directories_swaps_two_directories_whole(tmp_path, monkeypatch, exchange):
    import ctypes

    from tactile_compliance.outputs import exchange_directories

    old, new = tmp_path / "model", tmp_path / ".model.partial"
    for directory, text in ((old, "old"), (new, "new")):
        directory.mkdir()
        (directory / "weights").write_text(text)
        (directory / "config").write_text(text)
    if exchange == "two renames":  # no renameat2 (another OS, an old C library)

        def no_libc(*args, **kwargs):
            raise OSError("no C library")

        monkeypatch.setattr(ctypes, "CDLL", no_libc)
    exchange_directories(old, new)
    assert {p.name: p.read_text() for p in old.iterdir()} == {"weights": "new", "config": "new"}
    assert {p.name: p.read_text() for p in new.iterdir()} == {"weights": "old", "config": "old"}
    assert sorted(p.name for p in tmp_path.iterdir()) == [".model.partial", "model"]


def test_process_alive_tells_a_running_process_from_a_gone_or_reused_one() -> None:
    me = os.getpid()
    assert process_alive(me)
    start = process_start(me)
    assert process_alive(me, start)
    if start is not None:  # Linux: a pid reused by another process is not the owner
        assert not process_alive(me, start + "1")
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()  # reaped: its pid names no process now
    assert not process_alive(child.pid)


def test_commit_path_never_overwrites_unless_asked(tmp_path: Path) -> None:
    """The one atomic directory commit: the store replaces, the others never overwrite."""
    final, partial = tmp_path / "obj", tmp_path / ".partial-obj"
    partial.mkdir()
    (partial / "new.txt").write_text("new")
    commit_path(partial, final)
    assert (final / "new.txt").read_text() == "new" and not partial.exists()

    partial.mkdir()
    (partial / "newer.txt").write_text("newer")
    with pytest.raises(FileExistsError, match="nothing was overwritten"):
        commit_path(partial, final)
    assert sorted(p.name for p in final.iterdir()) == ["new.txt"]  # untouched

    commit_path(partial, final, replace=True)
    assert sorted(p.name for p in final.iterdir()) == ["newer.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["obj"]  # no partial, no old copy


def test_commit_path_puts_the_old_one_back_when_the_swap_fails(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    final = tmp_path / "store"
    final.mkdir()
    (final / "old.txt").write_text("old")
    real_replace = os.replace

    def failing(src: object, dst: object) -> None:
        if Path(str(src)).name == "missing-partial":
            raise OSError(28, "No space left on device")
        real_replace(src, dst)  # type: ignore[arg-type]

    monkeypatch.setattr(os, "replace", failing)
    with pytest.raises(OSError, match="No space left"):
        commit_path(tmp_path / "missing-partial", final, replace=True)
    assert (final / "old.txt").read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["store"]


def test_one_format_version_per_file_kind() -> None:
    check_format_version(2, 2, "x.pt: checkpoint")  # the one it reads
    for found, match in [
        (1, "x.pt: checkpoint format_version 1 is a pre-release format.*reads format 2 only"),
        (None, "format_version None is not an integer"),
        (True, "format_version True is not an integer"),
        (3, "format_version 3 is newer than this package reads.*upgrade"),
    ]:
        with pytest.raises(ValueError, match=match):
            check_format_version(found, 2, "x.pt: checkpoint")
