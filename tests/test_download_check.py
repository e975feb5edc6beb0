"""The download check (``data/download_check.py``, ``import burgess|yuan PATH --check``):
counts on a tree the generator wrote, and one line naming what is missing on truncated
copies of it (table-driven), on its zip and on Shore-hardness videos."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import zipfile
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest

from tactile_compliance.data.download_check import (
    IncompleteDownloadError,
    check_burgess_download,
    check_yuan_download,
)
from tactile_compliance.data.raw_layout import read_metadata
from tactile_compliance.synthetic.generate import generate_burgess_tree

GRASPS = 3


@pytest.fixture(scope="module")
def generated(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object]:
    """A tree `simulate` writes: 3 objects x 3 grasps at 24 x 32 px."""
    out = tmp_path_factory.mktemp("download") / "tree"
    report = generate_burgess_tree(
        out,
        n_objects=3,
        grasps_per_object=GRASPS,
        image_size=(24, 32),
        progress=False,
        workers=1,
    )
    return out, report


def _copy(generated: tuple[Path, object], tmp_path: Path) -> Path:
    tree = tmp_path / "tree"
    shutil.copytree(generated[0], tree)
    return tree


def _objects(tree: Path) -> list[Path]:
    return sorted(p for p in tree.iterdir() if p.is_dir())


def _write_table(tree: Path, path: Path) -> Path:
    """The dataset's object table for a tree: each object's grasps as Trials Recorded?."""
    rows = ["Label,Shape,Material,Modulus [Pa],Trials Recorded?"]
    for obj in _objects(tree):
        meta = read_metadata(obj)
        grasps = len(list(obj.glob("grasp=*")))
        rows.append(
            f"{obj.name},{meta['shape']},{meta['material']},{meta['youngs_modulus']},{grasps}"
        )
    path.write_text("\n".join(rows) + "\n")
    return path


def test_complete_generated_tree_counts_what_the_generator_wrote(generated, tmp_path):
    tree, report = generated
    check = check_burgess_download(tree)
    assert check.complete, check.error_line()
    assert check.counts["objects"] == report.objects_total == 3
    grasp_dirs = list(tree.glob("*/grasp=*"))
    sample_dirs = list(tree.glob("*/grasp=*/augmentation=*"))
    assert check.counts["grasps"] == len(grasp_dirs) == report.grasps - report.grasps_rejected
    assert check.counts["samples"] == len(sample_dirs) == report.samples
    # hidden files (the generator's output marker) are no part of a dataset
    files = [p for p in tree.rglob("*") if p.is_file() and not p.name.startswith(".")]
    assert check.counts["files"] == len(files)
    assert check.total_bytes == sum(p.stat().st_size for p in files)
    assert "Complete    yes" in check.format()
    table = check_burgess_download(tree, object_table=_write_table(tree, tmp_path / "t.csv"))
    assert table.complete, table.error_line()


def test_zip_of_the_tree_gives_the_same_counts(generated, tmp_path):
    tree = generated[0]
    archive = tmp_path / "gelsight_youngs_modulus_dataset.zip"
    with zipfile.ZipFile(archive, "w") as handle:
        for path in sorted(tree.rglob("*")):
            handle.write(path, Path("gelsight_youngs_modulus_dataset") / path.relative_to(tree))
    from_dir, from_zip = check_burgess_download(tree), check_burgess_download(archive)
    assert from_zip.complete, from_zip.error_line()
    assert from_zip.counts == from_dir.counts
    assert from_zip.total_bytes == from_dir.total_bytes
    # A zip cut short has no central directory: one error naming the size.
    archive.write_bytes(archive.read_bytes()[: archive.stat().st_size // 2])
    with pytest.raises(IncompleteDownloadError, match=r"not a readable zip .* download it again"):
        check_burgess_download(archive)


def _second_sample(tree: Path) -> Path:
    """The first ``augmentation=1`` directory (time shifts vary per grasp)."""
    return sorted(tree.glob("*/grasp=*/augmentation=1"))[0]


def _remove_file(tree: Path) -> str:
    path = _second_sample(tree) / "RGB.pkl"
    path.unlink()
    return rf"1 missing file \({path.relative_to(tree).as_posix()}\)"


def _remove_grasp(tree: Path) -> str:
    obj = _objects(tree)[1]
    shutil.rmtree(obj / "grasp=1")
    return rf"1 object with missing grasps \({obj.name}: 2 of the table's 3, no grasp=1\)"


def _remove_last_grasp(tree: Path) -> str:
    obj = _objects(tree)[1]
    shutil.rmtree(obj / f"grasp={GRASPS - 1}")
    return rf"1 object with missing grasps \({obj.name}: 2 of the table's 3\)"


def _truncate(tree: Path) -> str:
    path = _objects(tree)[2] / "grasp=2" / "augmentation=0" / "depth_markers.pkl"
    path.write_bytes(path.read_bytes()[:-100])
    return rf"1 truncated file \({path.relative_to(tree).as_posix()}\)"


def _empty(tree: Path) -> str:
    path = _objects(tree)[0] / "grasp=1" / "augmentation=0" / "forces.pkl"
    path.write_bytes(b"")
    return r"1 truncated file \(.*grasp=1/augmentation=0/forces.pkl\)"


def _remove_sample_dir(tree: Path) -> str:
    sample = _second_sample(tree).parent / "augmentation=0"
    shutil.rmtree(sample)
    return rf"1 missing sample directory \({sample.relative_to(tree).as_posix()}\)"


def _empty_grasp(tree: Path) -> str:
    grasp = _objects(tree)[2] / "grasp=0"
    for sample in grasp.glob("augmentation=*"):
        shutil.rmtree(sample)
    return r"1 grasp without samples \(.*/grasp=0\)"


def _remove_metadata(tree: Path) -> str:
    (_objects(tree)[0] / "metadata.json").unlink()
    return r"1 missing file \(.*/metadata.json\)"


def _remove_object(tree: Path) -> str:
    obj = _objects(tree)[2]
    shutil.rmtree(obj)
    return rf"1 missing object \({obj.name}\)"


def _remove_object_no_table(tree: Path) -> str:
    shutil.rmtree(_objects(tree)[0])
    return r"1 missing object \(1 of the 3 objects generation.json counts\)"


def _many_files(tree: Path) -> str:
    for path in sorted(tree.glob("*/grasp=*/augmentation=*/widths.pkl")):
        path.unlink()
    return r"\d+ missing files \(.*widths.pkl, .*widths.pkl, .*widths.pkl and \d+ more\)"


def _empty_directory(tree: Path) -> str:
    for child in tree.iterdir():
        shutil.rmtree(child) if child.is_dir() else child.unlink()
    return (
        r"1 missing object \(no object directories \(\{object\}/grasp=g/augmentation=k/\) at all\)"
    )


# (damage, with the object table)
CASES: dict[str, tuple[Callable[[Path], str], bool]] = {
    "a file removed": (_remove_file, False),
    "a grasp folder missing": (_remove_grasp, True),
    "the last grasp folder missing": (_remove_last_grasp, True),
    "a pickle cut short": (_truncate, False),
    "an empty pickle": (_empty, False),
    "augmentation=0 missing": (_remove_sample_dir, False),
    "a grasp folder emptied": (_empty_grasp, False),
    "metadata.json missing": (_remove_metadata, False),
    "an object missing from the table": (_remove_object, True),
    "an object missing from the generator's count": (_remove_object_no_table, False),
    "many files missing": (_many_files, False),
    "nothing unpacked": (_empty_directory, False),
}


@pytest.mark.parametrize("case", CASES, ids=list(CASES))
def test_truncated_copy_is_one_line_naming_what_is_missing(generated, tmp_path, case):
    tree = _copy(generated, tmp_path)
    table = _write_table(tree, tmp_path / "objects.csv") if CASES[case][1] else None
    expected = CASES[case][0](tree)
    check = check_burgess_download(tree, object_table=table)
    assert not check.complete
    with pytest.raises(IncompleteDownloadError) as caught:
        check.raise_if_incomplete()
    line = str(caught.value)
    assert "\n" not in line
    assert line.startswith(f"{tree} is incomplete: ")
    assert line.endswith("download or unpack it again (the counts are in the lines above)")
    assert len([kind for kind, paths in check.problems.items() if paths]) == 1, line
    assert __import__("re").search(expected, line), line
    assert "Complete    no" in check.format()


def test_grasp_gap_without_a_table_is_only_noted(generated, tmp_path):
    """The generator (and the recording rules) leave a rejected grasp's number unused."""
    tree = _copy(generated, tmp_path)
    shutil.rmtree(_objects(tree)[1] / "grasp=1")
    check = check_burgess_download(tree)
    assert check.complete
    assert any("grasp numbers skip 1" in note for note in check.notes)


def test_check_is_torch_free(generated):
    code = (
        "import sys; from tactile_compliance.data.download_check import check_burgess_download;"
        f"check_burgess_download({str(generated[0])!r}); print('torch' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def _video(path: Path, frames: int = 4) -> None:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30, (32, 24))
    for level in range(frames):
        writer.write(np.full((24, 32, 3), 40 * level, np.uint8))
    writer.release()


def test_yuan_videos_counted_and_empty_or_damaged_ones_named(tmp_path):
    for name in ("BASIC_34_1.avi", "BASIC_34_2.avi", "EDGE_8_1.avi"):
        _video(tmp_path / name)
    (tmp_path / "notes.avi").write_bytes(b"")  # outside the name pattern, and empty
    check = check_yuan_download(tmp_path)
    assert check.counts == {"objects": 2, "videos": 4}
    assert any("the paper reports 371" in note for note in check.notes)
    assert any("Shore 00 hardness 8-34" in note for note in check.notes)
    assert check.error_line().startswith(f"{tmp_path} is incomplete: 1 empty video (notes.avi)")
    (tmp_path / "notes.avi").unlink()
    (tmp_path / "EDGE_8_2.avi").write_bytes(b"RIFF not a video")
    check = check_yuan_download(tmp_path)
    assert "1 unreadable video (EDGE_8_2.avi)" in check.error_line()
    (tmp_path / "EDGE_8_2.avi").unlink()
    assert check_yuan_download(tmp_path).complete


# ------------------------------------------------------------------ command line
def _cli(*args: str):  # type: ignore[no-untyped-def]
    from typer.testing import CliRunner

    from tactile_compliance.cli import app

    return CliRunner().invoke(app, list(args))


def test_cli_check_prints_the_counts_and_writes_nothing(generated):
    tree = generated[0]
    before = sorted(p.name for p in tree.parent.iterdir())
    result = _cli("import", "burgess", str(tree), "--check")
    assert result.exit_code == 0, result.output
    assert "Objects     3" in result.stdout and "Complete    yes" in result.stdout
    assert sorted(p.name for p in tree.parent.iterdir()) == before
    as_json = _cli("import", "burgess", str(tree), "--check", "--json")
    assert as_json.exit_code == 0, as_json.output
    document = json.loads(as_json.stdout)
    assert document["complete"] is True and document["problems"] == {}
    assert document["counts"] == check_burgess_download(tree).counts


@pytest.mark.parametrize("case", ["a file removed", "a grasp folder missing"])
def test_cli_check_of_a_truncated_copy_is_one_error_line(generated, tmp_path, case):
    tree = _copy(generated, tmp_path)
    damage, with_table = CASES[case]
    args = ["--objects", str(_write_table(tree, tmp_path / "t.csv"))] if with_table else []
    expected = damage(tree)
    result = _cli("import", "burgess", str(tree), "--check", *args)
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {tree} is incomplete: "), lines
    assert __import__("re").search(expected, lines[0]), lines[0]
    assert "Complete    no" in result.stdout


@pytest.mark.parametrize(
    ("args", "cause"),
    [
        (["import", "burgess", "{tree}"], "Missing option '--out'"),
        (["import", "yuan", "{tree}"], "Missing option '--out'"),
        (["import", "burgess", "{tree}", "--check", "--out", "s"], "--check writes nothing"),
        (["import", "burgess", "{tmp}/absent", "--check"], "no such directory or zip"),
        (["import", "yuan", "{tmp}/absent", "--check"], "no such directory of videos"),
        (["import", "burgess", "{tmp}/x.zip", "--check"], "not a readable zip"),
    ],
)
def test_cli_check_mistakes_are_one_line(generated, tmp_path, args, cause):
    (tmp_path / "x.zip").write_bytes(b"PK\x03\x04 cut short")
    args = [a.format(tree=generated[0], tmp=tmp_path) for a in args]
    result = _cli(*args)
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and cause in lines[0], lines
    assert not (tmp_path / "s").exists()
