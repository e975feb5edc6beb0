"""Is a downloaded public dataset complete? Counts, sizes and the missing or damaged
parts of a GelSight Young's-modulus tree (or its zip) and of a Shore-hardness video
directory, without unpickling or decoding anything: ``import burgess PATH --check`` and
``import yuan PATH --check``.

Torch-free and fast: a directory walk, one byte read per pickle (a pickle ends with the
STOP opcode, so a file cut short almost never does) and, for videos, the container
header. The layout's names come from :mod:`~tactile_compliance.data.raw_layout`; the
expected counts from what the dataset holds (docs/reproduce.md, "Check the download").
"""

from __future__ import annotations

import json
import os
import zipfile
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

from tactile_compliance.data.import_report import DataImportError, ImportPathError
from tactile_compliance.data.raw_layout import (
    AUGMENTATION_DIR,
    ESTIMATE_FILES,
    FINGER_FILES,
    FORCES_FILE,
    GRASP_DIR,
    METADATA_FILE,
    SYNTHETIC_MANIFEST,
    VIDEO_SUFFIXES,
    WIDTHS_FILE,
)

#: The files every ``augmentation=k`` directory of the public dataset holds (both fingers'
#: frames and depth maps, forces, widths); the two estimate files are left out where the
#: fit failed (:data:`raw_layout.ESTIMATE_FILES`).
REQUIRED_SAMPLE_FILES: tuple[str, ...] = (
    *(name for files in FINGER_FILES.values() for name in files),
    FORCES_FILE,
    WIDTHS_FILE,
)
#: The release as docs/reproduce.md describes it (from the project's reference notes).
BURGESS_ZIP_NAME = "gelsight_youngs_modulus_dataset.zip"
BURGESS_ZIP_GB = 20.7  # "~20.7 GB": approximate, so only shown, never compared
YUAN_OBJECTS = 371  # the paper's count of objects (Shore 00 8-87)
#: How many paths an error line names per kind of problem before "and N more".
SHOWN = 3
_PICKLE_STOP = b"."


class IncompleteDownloadError(DataImportError):
    """The download is missing files, directories or objects, or holds damaged files."""


@dataclass
class DownloadCheck:
    """What a dataset check found.

    Attributes:
        path: the directory or zip checked.
        counts: name -> count (``objects``, ``grasps``, ``samples``, ``files``, ``videos``).
        total_bytes: bytes of all files found (uncompressed sizes for a zip).
        problems: kind (e.g. ``missing file``) -> the paths (relative to ``path``), the
            download is incomplete when any is listed.
        notes: lines shown with the counts (expected values, what cannot be judged here).
    """

    path: Path
    counts: dict[str, int] = field(default_factory=dict)
    total_bytes: int = 0
    problems: dict[str, list[str]] = field(default_factory=lambda: defaultdict(list))
    notes: list[str] = field(default_factory=list)

    @property
    def complete(self) -> bool:
        return not any(self.problems.values())

    def error_line(self) -> str:
        """One line: how many of each kind of problem, the first few paths, the fix."""
        parts = []
        for kind, paths in self.problems.items():
            if not paths:
                continue
            shown = ", ".join(paths[:SHOWN]) + (
                f" and {len(paths) - SHOWN} more" if len(paths) > SHOWN else ""
            )
            parts.append(f"{len(paths)} {kind}{'s' if len(paths) != 1 else ''} ({shown})")
        return (
            f"{self.path} is incomplete: {'; '.join(parts)}; download or unpack it again "
            "(the counts are in the lines above)"
        )

    def format(self) -> str:
        """The counts, sizes and notes, one line each (the verdict last)."""
        lines = [f"Checked     {self.path}"]
        lines += [f"{name.capitalize():<11} {n:,}" for name, n in self.counts.items()]
        size = self.total_bytes
        shown = f"{size / 1e9:.2f} GB" if size >= 1e9 else f"{size / 1e6:.1f} MB"
        lines.append(f"{'Size':<11} {shown} ({size:,} bytes)")
        lines += [f"Note        {note}" for note in self.notes]
        lines.append("Complete    yes" if self.complete else "Complete    no")
        return "\n".join(lines)

    def to_dict(self) -> dict[str, object]:
        """The check as JSON-ready data (``--check --json``)."""
        return {
            "path": str(self.path),
            "complete": self.complete,
            "counts": dict(self.counts),
            "total_bytes": self.total_bytes,
            "problems": {kind: paths for kind, paths in self.problems.items() if paths},
            "notes": list(self.notes),
        }

    def raise_if_incomplete(self) -> None:
        """Raises IncompleteDownloadError (:meth:`error_line`) when a problem was found."""
        if not self.complete:
            raise IncompleteDownloadError(self.error_line())


def _plural(n: int, word: str) -> str:
    return f"{n:,} {word}{'' if n == 1 else 's'}"


# ----------------------------------------------------------------- GelSight tree
def _walk(root: Path) -> tuple[dict[str, int], set[str]]:
    """Relative POSIX path -> size in bytes of every file under ``root``, and the relative
    directories (hidden entries, such as an import's partial directories, left out)."""
    files: dict[str, int] = {}
    directories: set[str] = set()
    for directory, dirs, names in os.walk(root):
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        relative = Path(directory).relative_to(root)
        directories.update((relative / d).as_posix() for d in dirs)
        for name in names:
            if not name.startswith("."):
                files[(relative / name).as_posix()] = os.stat(Path(directory, name)).st_size
    return files, directories


def _zip_entries(path: Path) -> tuple[dict[str, int], set[str]]:
    """The files (uncompressed sizes) and directories a zip lists, relative to its one top
    directory when it has one (hidden entries left out, as :func:`_walk` does)."""
    try:
        with zipfile.ZipFile(path) as archive:
            infos = archive.infolist()
    except (zipfile.BadZipFile, OSError) as err:
        size_gb = path.stat().st_size / 1e9
        raise IncompleteDownloadError(
            f"{path}: not a readable zip ({err}; {size_gb:.2f} GB on disk, the release is "
            f"~{BURGESS_ZIP_GB} GB): the download is cut short or damaged, download it again"
        ) from None
    names = [PurePosixPath(info.filename) for info in infos]
    strip = len({n.parts[0] for n in names}) == 1 and any(len(n.parts) > 1 for n in names)
    files: dict[str, int] = {}
    directories: set[str] = set()
    for info, name in zip(infos, names, strict=True):
        if len(name.parts) <= strip or any(part.startswith(".") for part in name.parts):
            continue  # hidden entries, as in a directory walk
        relative = PurePosixPath(*name.parts[strip:]).as_posix()
        if info.is_dir():
            directories.add(relative)
        else:
            files[relative] = info.file_size
            directories.update(p.as_posix() for p in PurePosixPath(relative).parents[:-1])
    return files, directories


def _truncated_pickle(path: Path, size: int) -> bool:
    """Whether a pickle file is empty or does not end with the STOP opcode."""
    if size == 0:
        return True
    with open(path, "rb") as handle:
        handle.seek(size - 1)
        return handle.read(1) != _PICKLE_STOP


def _object_counts(table_path: Path) -> dict[str, int]:
    """Object name -> grasps recorded (the table's ``Trials Recorded?``; 0 when empty)."""
    from tactile_compliance.data.object_table import read_object_table

    table = read_object_table(table_path)
    if "trials_recorded" not in table.columns:
        raise ImportPathError(
            f"{table_path}: no 'Trials Recorded?' column: the check takes each object's "
            "grasp count from it; pass the dataset's dataset_objects_and_compliance.csv"
        )
    trials = table["trials_recorded"].fillna(0)
    return {str(name): int(n) for name, n in trials.items()}


Tree = dict[str, dict[int, dict[int, set[str]]]]


def _index(
    entries: dict[str, int], directories: set[str]
) -> tuple[Tree, dict[str, set[str]], set[str]]:
    """object -> grasp -> augmentation -> file names (from the directories too, so an
    empty grasp or sample directory is seen); the objects' own files, of the objects
    that hold ``metadata.json``; the files at the root. An object is a directory with
    ``metadata.json`` or ``grasp=g`` directories, as the importer finds them."""
    tree: Tree = defaultdict(dict)
    object_files: dict[str, set[str]] = defaultdict(set)
    root_files: set[str] = set()
    for relative in sorted(directories):
        parts = PurePosixPath(relative).parts
        if len(parts) >= 2 and (grasp := GRASP_DIR.match(parts[1])):
            augmentations = tree[parts[0]].setdefault(int(grasp.group(1)), {})
            if len(parts) == 3 and (aug := AUGMENTATION_DIR.match(parts[2])):
                augmentations.setdefault(int(aug.group(1)), set())
    for relative in entries:
        parts = PurePosixPath(relative).parts
        if len(parts) == 1:
            root_files.add(parts[0])
        elif len(parts) == 2:
            object_files[parts[0]].add(parts[1])
        elif (
            len(parts) == 4
            and (grasp := GRASP_DIR.match(parts[1]))
            and (aug := AUGMENTATION_DIR.match(parts[2]))
        ):
            grasps = tree[parts[0]].setdefault(int(grasp.group(1)), {})
            grasps.setdefault(int(aug.group(1)), set()).add(parts[3])
    labelled = {name: files for name, files in object_files.items() if METADATA_FILE in files}
    return tree, labelled, root_files


def check_burgess_download(
    path: str | Path, *, object_table: str | Path | None = None
) -> DownloadCheck:
    """Check an unpacked GelSight Young's-modulus dataset directory, or its zip.

    Certain problems (``problems``): an object directory without ``metadata.json`` (unless
    a table labels it) or without grasps; a grasp directory without ``augmentation=0``, or
    with a gap in its augmentation numbers (the time shifts are 0, 1, ... by
    construction); a sample directory without one of :data:`REQUIRED_SAMPLE_FILES`; an
    empty or cut-short pickle (directories only: a zip's members are not read); a
    ``metadata.json`` that is no JSON; objects the object table lists, or a generated
    tree's ``generation.json`` counts, that are absent; with ``object_table``, an object
    with fewer grasps than its ``Trials Recorded?``. Gaps in an object's grasp numbers
    are only noted without a table (a grasp the recording rules rejected leaves one).

    Args:
        path: the ``gelsight_youngs_modulus_dataset/`` directory (or a copy in the same
            layout, e.g. one ``simulate`` wrote) or ``gelsight_youngs_modulus_dataset.zip``.
        object_table: ``dataset_objects_and_compliance.csv``: the objects and the grasps
            each should have.

    Raises:
        ImportPathError: ``path`` is missing or neither a directory nor a file.
        IncompleteDownloadError: a zip that cannot be read (cut short).
        ObjectTableError: the table cannot be read.
    """
    root = Path(path)
    if not root.exists():
        raise ImportPathError(f"{root}: no such directory or zip")
    check = DownloadCheck(root)
    is_zip = root.is_file()
    entries, directories = _zip_entries(root) if is_zip else _walk(root)
    expected = _object_counts(Path(object_table)) if object_table is not None else None

    tree, object_files, root_files = _index(entries, directories)
    objects = sorted(set(object_files) | set(tree))
    if not objects:
        check.problems["missing object"].append(
            "no object directories ({object}/grasp=g/augmentation=k/) at all"
        )
    samples = 0
    gaps: list[str] = []
    for name in objects:
        grasps = tree.get(name, {})
        if METADATA_FILE not in object_files.get(name, set()) and (
            expected is None or name not in expected
        ):
            check.problems["missing file"].append(f"{name}/{METADATA_FILE}")
        elif not is_zip and METADATA_FILE in object_files.get(name, set()):
            try:
                json.loads((root / name / METADATA_FILE).read_text(encoding="utf-8"))
            except (ValueError, OSError):
                check.problems["damaged file"].append(f"{name}/{METADATA_FILE}")
        if not grasps:
            check.problems["object without grasps"].append(name)
            continue
        numbers = sorted(grasps)
        skipped = sorted(set(range(numbers[-1] + 1)) - set(numbers))
        gaps += [f"{name}/grasp={g}" for g in skipped]
        if expected is not None and name in expected and len(grasps) < expected[name]:
            absent = f", no {', '.join(f'grasp={g}' for g in skipped)}" if skipped else ""
            check.problems["object with missing grasps"].append(
                f"{name}: {len(grasps)} of the table's {expected[name]}{absent}"
            )
        for g in numbers:
            augmentations = grasps[g]
            if not augmentations:
                check.problems["grasp without samples"].append(f"{name}/grasp={g}")
                continue
            ks = sorted(augmentations)
            check.problems["missing sample directory"].extend(
                f"{name}/grasp={g}/augmentation={k}" for k in sorted(set(range(ks[-1])) - set(ks))
            )
            for k in ks:
                samples += 1
                base = f"{name}/grasp={g}/augmentation={k}"
                present = augmentations[k]
                check.problems["missing file"].extend(
                    f"{base}/{f}" for f in REQUIRED_SAMPLE_FILES if f not in present
                )
                if not is_zip:
                    check.problems["truncated file"].extend(
                        f"{base}/{f}"
                        for f in sorted(present)
                        if f.endswith(".pkl")
                        and _truncated_pickle(root / base / f, entries[f"{base}/{f}"])
                    )
    if expected is not None:
        absent = [name for name, n in expected.items() if n > 0 and name not in tree]
        check.problems["missing object"].extend(
            a for a in absent if a not in check.problems["object without grasps"]
        )
    elif SYNTHETIC_MANIFEST in root_files and not is_zip:
        try:
            promised = int(json.loads((root / SYNTHETIC_MANIFEST).read_text())["objects"])
        except (OSError, ValueError, KeyError, TypeError):
            check.problems["damaged file"].append(SYNTHETIC_MANIFEST)
        else:
            if len(objects) < promised:
                check.problems["missing object"].append(
                    f"{promised - len(objects)} of the {promised} objects {SYNTHETIC_MANIFEST}"
                    " counts"
                )

    n_grasps = sum(len(g) for g in tree.values())
    check.counts = {
        "objects": len(objects),
        "grasps": n_grasps,
        "samples": samples,
        "files": len(entries),
    }
    check.total_bytes = sum(entries.values())
    per_object = Counter(len(g) for g in tree.values())
    check.notes.append(
        "grasps per object: "
        + ", ".join(f"{k}: {_plural(n, 'object')}" for k, n in sorted(per_object.items()))
    )
    if expected is not None:
        listed = sum(1 for n in expected.values() if n > 0)
        check.notes.append(
            f"the object table lists {_plural(listed, 'object')} with "
            f"{sum(expected.values()):,} grasps (Trials Recorded?)"
        )
    elif gaps:
        check.notes.append(
            f"grasp numbers skip {len(gaps)} ({', '.join(gaps[:SHOWN])}): a grasp the "
            "recording rules rejected, or a missing folder; --objects TABLE checks the counts"
        )
    estimates = Counter(
        f
        for grasps in tree.values()
        for augmentations in grasps.values()
        for present in augmentations.values()
        for f in ESTIMATE_FILES
        if f in present
    )
    check.notes.append(
        "samples with estimates: "
        + ", ".join(f"{f} {estimates[f]:,} of {samples:,}" for f in ESTIMATE_FILES)
        + " (absent where the fit failed)"
    )
    if is_zip:
        check.notes.append(
            f"zip of {root.stat().st_size / 1e9:.2f} GB (the release: ~{BURGESS_ZIP_GB} GB); "
            "its members were listed, not read: check the unpacked directory too"
        )
    return check


# ----------------------------------------------------------------- Shore videos
def check_yuan_download(path: str | Path) -> DownloadCheck:
    """Check a directory of Shore-hardness press videos (``{SHAPE}_{hardness}_{n}.avi``).

    Problems: an empty video file, or one whose container header cannot be read. Noted:
    the objects found against the paper's 371, the hardness range (the paper: Shore 00
    8-87), and files with a video suffix outside the name pattern (``import yuan``
    skips them).

    Raises:
        ImportPathError: ``path`` is not a directory.
    """
    from tactile_compliance.data.yuan import VIDEO_NAME, video_frame_size

    root = Path(path)
    if not root.is_dir():
        raise ImportPathError(f"{root}: no such directory of videos")
    check = DownloadCheck(root)
    videos = sorted(
        p for p in root.rglob("*") if p.suffix.lower() in VIDEO_SUFFIXES and p.is_file()
    )
    objects: set[str] = set()
    hardness: list[int] = []
    unnamed: list[str] = []
    for video in videos:
        relative = video.relative_to(root).as_posix()
        size = video.stat().st_size
        check.total_bytes += size
        match = VIDEO_NAME.match(video.name)
        if match is None:
            unnamed.append(relative)
        else:
            objects.add(f"{match['shape']}_{match['hardness']}")
            hardness.append(int(match["hardness"]))
        if size == 0:
            check.problems["empty video"].append(relative)
        elif video_frame_size(video) is None:
            check.problems["unreadable video"].append(relative)
    if not videos:
        check.problems["missing video"].append(f"no {', '.join(VIDEO_SUFFIXES)} files")
    check.counts = {"objects": len(objects), "videos": len(videos)}
    check.notes.append(f"objects: {len(objects):,} found, the paper reports {YUAN_OBJECTS}")
    if hardness:
        check.notes.append(f"Shore 00 hardness {min(hardness)}-{max(hardness)} (the paper: 8-87)")
    if unnamed:
        check.notes.append(
            f"{_plural(len(unnamed), 'video')} not named {{SHAPE}}_{{hardness}}_{{n}}"
            f" ({', '.join(unnamed[:SHOWN])}): import yuan skips them"
        )
    return check
