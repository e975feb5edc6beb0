"""Importer for the GelSight Young's-modulus dataset layout (Burgess et al. 2024), real or
generated: each (grasp, augmentation, finger) becomes one store sample.

See docs/data.md, "Importing the GelSight Young's-modulus dataset" and "Bad input".
"""

from __future__ import annotations

import json
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import pandas as pd

from tactile_compliance.data import plausibility
from tactile_compliance.data.image_ops import resize_frames
from tactile_compliance.data.import_report import (
    ImportPathError,
    ImportReport,
    ImportUnitsError,
    NothingImportedError,
    import_paths,
    store_writing,
    utf8_problem,
)
from tactile_compliance.data.object_table import read_object_table, valid_modulus
from tactile_compliance.data.raw_layout import (
    AUGMENTATION_DIR,
    ESTIMATE_FILES,
    FINGER_FILES,
    FORCES_FILE,
    GRASP_DIR,
    METADATA_FILE,
    RIG_ESTIMATE_FILES,
    SYNTHETIC_MANIFEST,
    WIDTHS_FILE,
    FingerChoice,
    SampleError,
    load_depth,
    load_estimate,
    load_frames,
    load_vector,
    numbered_dirs,
    read_metadata,
    sample_grasp_dir,
    tree_units,
)
from tactile_compliance.data.safe_pickle import peek_array_shape
from tactile_compliance.data.store import (
    ESTIMATE_COLUMNS,
    RIG_ESTIMATE_COLUMNS,
    UNIT_COLUMNS,
    depth_size_for,
)
from tactile_compliance.data.store_writer import GraspStoreWriter
from tactile_compliance.physics.estimators import DEFAULT_ESTIMATOR
from tactile_compliance.progress import progress_bar


@dataclass(frozen=True)
class ObjectLabel:
    """Ground truth of one object."""

    name: str
    modulus_pa: float
    material: str
    shape: str


def _object_label(
    object_dir: Path, table: pd.DataFrame | None, report: ImportReport
) -> ObjectLabel | None:
    """Labels from the object table when given, else from metadata.json; None = skip object."""
    name = object_dir.name
    problem = utf8_problem(name)
    if problem:
        report.problem(object_dir, f"invalid name: the object directory name is {problem}")
        return None
    if table is not None:
        if name not in table.index:
            report.problem(object_dir, "object absent from the object table")
            return None
        row = table.loc[name]
        modulus, material, shape = row["modulus_pa"], row["material"], row["shape"]
    else:
        metadata_path = object_dir / METADATA_FILE
        try:
            metadata = read_metadata(object_dir)
        except FileNotFoundError as err:
            report.problem(object_dir, f"{err} (pass --objects TABLE.csv to label it)")
            return None
        except ValueError as err:
            report.problem(metadata_path, str(err))
            return None
        modulus = metadata.get("youngs_modulus")
        # JSON has numbers: text ("1e6") and booleans (true) are never cast to one.
        if isinstance(modulus, bool) or not isinstance(modulus, (int, float)):
            kind = "null" if modulus is None else type(modulus).__name__
            kind = {"str": "text", "bool": "a boolean"}.get(kind, kind)
            report.problem(
                object_dir,
                f"invalid modulus: {modulus!r} is {kind}, not a JSON number "
                f"(text and booleans are never cast)",
            )
            return None
        material = metadata.get("material", "")
        shape = metadata.get("shape", "")
        for field_name, text in (("material", material), ("shape", shape)):
            problem = utf8_problem(str(text))
            if problem:
                report.problem(metadata_path, f"invalid metadata.json: {field_name} is {problem}")
                return None
    if not valid_modulus(modulus):
        must = plausibility.MODULUS.requirement()
        report.problem(object_dir, f"invalid modulus: {modulus!r} (must be {must})")
        return None
    problem = plausibility.MODULUS.violation(float(modulus))  # type: ignore[arg-type]
    if problem:
        report.problem(object_dir, f"invalid modulus: {modulus!r}: {problem}")
        return None
    return ObjectLabel(name, float(modulus), str(material), str(shape))  # type: ignore[arg-type]


def _sample_dirs(object_dir: Path, report: ImportReport) -> list[tuple[int, int, Path]]:
    """(grasp, augmentation, directory) of an object; unlistable directories are reported."""
    found: list[tuple[int, int, Path]] = []
    try:
        grasps = numbered_dirs(object_dir, GRASP_DIR)
    except OSError as err:
        report.problem(object_dir, f"unreadable directory: {err.strerror or err}")
        return found
    unreadable = False
    for grasp, grasp_dir in grasps:
        try:
            augmentations = numbered_dirs(grasp_dir, AUGMENTATION_DIR)
        except OSError as err:
            report.problem(grasp_dir, f"unreadable directory: {err.strerror or err}")
            unreadable = True
            continue
        found.extend((grasp, augmentation, aug_dir) for augmentation, aug_dir in augmentations)
    if not found and not unreadable:
        report.problem(object_dir, "no grasp=g/augmentation=k directories")
    return found


def _object_dirs(src: Path) -> list[Path]:
    # A directory is an object when it holds metadata.json or grasp=* directories.
    try:
        children = sorted(src.iterdir())
    except OSError as err:
        raise ImportPathError(f"{src}: cannot list the source directory ({err})") from err
    return [
        d
        for d in children
        if d.is_dir()
        and not d.name.startswith(".")
        and ((d / METADATA_FILE).exists() or any(d.glob("grasp=*")))
    ]


def _present_fingers(
    samples: list[tuple[ObjectLabel, int, int, Path]],
    finger_names: list[str],
    fingers: str,
    src: Path,
    report: ImportReport,
) -> list[str]:
    """The fingers to import: ``finger_names`` less a finger no sample has a file of.

    A tree in which no sample holds the marker finger's image file (a markerless-only
    recording, as ``record`` writes) is imported with the markerless finger alone when
    ``fingers`` is ``both``, and the report says so (``report.fingers_note``) instead of a
    missing file per sample. Asking for one finger that no sample has is an error.

    Raises:
        NothingImportedError: ``fingers`` names a finger of which no sample has a file.
    """
    present = [
        finger
        for finger in finger_names
        if any((d / FINGER_FILES[finger][0]).is_file() for _, _, _, d in samples)
    ]
    if not samples or present == finger_names:
        return finger_names
    missing = [f for f in finger_names if f not in present]
    files = ", ".join(FINGER_FILES[f][0] for f in missing)
    if not present:
        other = "markerless" if fingers == "markers" else "markers"
        raise NothingImportedError(
            f"{src}: no sample has {files} (the {fingers} finger); "
            f"import the other finger with --fingers {other}",
            report=report,
        )
    report.fingers_note = (
        f"Fingers: {', '.join(present)} only: no sample has {files} "
        f"(a {present[0]}-only recording, as `record` writes); imported {len(samples)} "
        f"sample directories with {', '.join(present)} frames."
    )
    return present


def majority_frame_size(
    samples: list[tuple[ObjectLabel, int, int, Path]], image_files: list[str], progress: bool
) -> tuple[tuple[int, int] | None, Counter[tuple[int, int]]]:
    """The most common (H, W) that the image pickles declare, read without loading them
    (ties: the size met first), and the counts; (None, empty) when none could be read."""
    sizes: Counter[tuple[int, int]] = Counter()
    with progress_bar("Reading frame sizes", total=len(samples), enabled=progress) as advance:
        for _, _, _, aug_dir in samples:
            for image_file in image_files:
                shape = peek_array_shape(aug_dir / image_file)
                if shape is not None and len(shape) == 4 and shape[::3] == (3, 3) and min(shape):
                    sizes[(shape[1], shape[2])] += 1
            advance()
    return (sizes.most_common(1)[0][0] if sizes else None), sizes


def _tree_estimator(src: Path) -> str:
    """The analytical estimator (``physics.estimators`` name) of a tree's grasps that name
    no units (``raw_layout.tree_units``): the one a generated tree's manifest names, else
    ``DEFAULT_ESTIMATOR`` (the public dataset's own code). ImportPathError: a manifest
    naming none."""
    manifest = src / SYNTHETIC_MANIFEST
    if not manifest.is_file():
        return DEFAULT_ESTIMATOR.name
    try:
        return str(json.loads(manifest.read_text())["analytical_estimator"])
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise ImportPathError(
            f"{manifest}: names no analytical_estimator ({err!r}); a pre-release generator "
            f"wrote it: generate the tree again"
        ) from None


def import_burgess(
    src_dir: str | Path,
    out_dir: str | Path,
    *,
    object_table: str | Path | None = None,
    fingers: FingerChoice = "both",
    image_size: tuple[int, int] | None = None,
    strict: bool = False,
    overwrite: bool = False,
    progress: bool = True,
    source_name: str | None = None,
    depth: bool = True,
) -> ImportReport:
    """Import a GelSight Young's-modulus dataset tree into a GraspStore at ``out_dir``.

    Args:
        src_dir: the unpacked ``gelsight_youngs_modulus_dataset/`` directory.
        object_table: CSV with the dataset's columns; when given, labels come from it.
        fingers: ``both`` gives two samples per grasp and augmentation.
        image_size: (height, width) px to resize the dataset's majority-size frames to
            (samples of another size are skipped and reported); None keeps the size.
        strict: stop at the first problem instead of skipping and reporting it.
        overwrite: replace an existing store, and only a store: the new one replaces it
            atomically once complete (``GraspStoreWriter``), so a failed import keeps it.
        source_name: recorded in the store header; default ``synthetic`` for trees written
            by the generator (they hold ``generation.json``), else ``burgess``.
        depth: keep each sample's three depth maps (its own finger's ``depth*.pkl``) in
            the store (docs/data.md, "Depth maps").

    Raises:
        DataImportError: one of its subclasses (``import_report``) when the import cannot
            go on; nothing is written then.
    """
    start = time.perf_counter()
    src, out = import_paths(src_dir, out_dir, overwrite)
    if source_name is None:
        source_name = "synthetic" if (src / SYNTHETIC_MANIFEST).is_file() else "burgess"
    if fingers not in ("markerless", "markers", "both"):
        raise ValueError(f"fingers must be markerless, markers or both, got {fingers!r}")
    finger_names = list(FINGER_FILES) if fingers == "both" else [fingers]
    table = read_object_table(object_table) if object_table is not None else None
    report = ImportReport(
        source=source_name, source_dir=str(src), store_dir=str(out), strict=strict
    )

    object_dirs = _object_dirs(src)
    report.objects_seen = len(object_dirs)
    report.require_sources(object_dirs, src, "object directories (expected {object}/grasp=g/...)")
    samples: list[tuple[ObjectLabel, int, int, Path]] = []
    for object_dir in object_dirs:
        label = _object_label(object_dir, table, report)
        if label is not None:
            samples.extend((label, g, k, d) for g, k, d in _sample_dirs(object_dir, report))
    finger_names = _present_fingers(samples, finger_names, fingers, src, report)
    image_files = [FINGER_FILES[finger][0] for finger in finger_names]
    source_hw, sizes = majority_frame_size(samples, image_files, progress)
    # Before anything is written: a damaged manifest or units file, or grasps in two units,
    # stop here. Grasps without units.json (the public dataset's) take the dataset's
    # heuristic, and the report says how many did.
    try:
        found = tree_units(
            (sample_grasp_dir(d) for _, _, _, d in samples), unnamed_estimator=_tree_estimator(src)
        )
    except ValueError as err:
        raise ImportUnitsError(f"{src}: {err}; nothing was imported", report=report) from None
    report.units = found.units.describe()
    if found.mixed_rigs:
        rigs = ", ".join(
            "none" if k is None else f"{k:.4g} N/m" for k in found.rig_stiffnesses_n_per_m
        )
        report.units += (
            f"; no rig-corrected estimates imported: the grasps name different rigs ({rigs}), "
            "so an FWR model cannot train on this store"
        )
    report.grasps_without_units = len(found.unnamed)
    unit_columns = dict(zip(UNIT_COLUMNS, found.units.to_row(), strict=True))
    # Rig-corrected estimates mean something only at the stiffness the units name.
    estimate_files = dict(zip(ESTIMATE_COLUMNS, ESTIMATE_FILES, strict=True))
    if found.units.rig_stiffness_n_per_m is not None:
        estimate_files |= dict(zip(RIG_ESTIMATE_COLUMNS, RIG_ESTIMATE_FILES, strict=True))

    def store_depth_size() -> tuple[int, int] | None:
        size = image_size or source_hw
        return depth_size_for(size) if depth and size is not None else None

    def make_writer() -> GraspStoreWriter:
        return GraspStoreWriter(
            out,
            image_size=image_size or source_hw,
            depth_size=store_depth_size(),
            source=source_name,
            creation_parameters={
                "importer": "burgess",
                "source_dir": str(src.resolve()),
                "object_table": str(object_table) if object_table else None,
                "fingers": fingers if len(finger_names) > 1 else finger_names[0],
                "source_image_size": list(source_hw),
                "source_image_sizes": {f"{h}x{w}": n for (h, w), n in sizes.most_common()},
                "frame_kind": "difference",
                "depth": bool(depth),
            },
            overwrite=overwrite,
        )

    objects_imported: set[str] = set()
    with (
        store_writing(out, report, make_writer) as target,
        progress_bar("Importing samples", total=len(samples), enabled=progress) as advance,
    ):
        for label, grasp, augmentation, aug_dir in samples:
            advance()
            try:
                forces_n = load_vector(aug_dir, FORCES_FILE)
                widths_m = load_vector(aug_dir, WIDTHS_FILE)
                estimates = {c: load_estimate(aug_dir, f) for c, f in estimate_files.items()}
            except SampleError as err:
                report.problem(aug_dir, str(err))
                continue
            for finger in finger_names:
                image_file, depth_file = FINGER_FILES[finger]
                try:
                    frames = load_frames(aug_dir, image_file, source_hw)
                    if source_hw is None:  # no size could be peeked: the first decides
                        source_hw = (frames.shape[1], frames.shape[2])
                    depth_max_mm, depth_maps = load_depth(aug_dir, depth_file, store_depth_size())
                    frames = resize_frames(frames, image_size)
                except SampleError as err:
                    report.problem(aug_dir / image_file, str(err))
                    continue
                row = {
                    "object": label.name,
                    "grasp": grasp,
                    "augmentation": augmentation,
                    "finger": finger,
                    "material": label.material,
                    "shape": label.shape,
                    "modulus_pa": label.modulus_pa,
                    **{f"force_n_{i}": forces_n[i] for i in range(3)},
                    **{f"width_m_{i}": widths_m[i] for i in range(3)},
                    **estimates,
                    **{f"depth_max_mm_{i}": depth_max_mm[i] for i in range(3)},
                    **unit_columns,
                    "source_path": str((aug_dir / image_file).relative_to(src)),
                }
                if target.append(frames, row, aug_dir / image_file, depth_maps):
                    objects_imported.add(label.name)
        report.objects_imported = len(objects_imported)
        target.commit(
            f"{src}: nothing importable, every sample was skipped ({len(report.problems)} problems)"
        )
    report.seconds = time.perf_counter() - start
    return report
