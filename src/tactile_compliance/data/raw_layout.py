"""The raw layout of the GelSight Young's-modulus dataset (Burgess et al. 2024): its names,
its one reader (``import burgess``, ``predict``) and its one writer (the generator,
``record``); every ``.pkl`` is read with the allow-list unpickler and checked against its
file's plausibility rule (:data:`FILE_RULES`). The files and their units::

    ROOT/{object}/metadata.json
    ROOT/{object}/grasp={g}/units.json             estimator, depth model, px/mm (ours only)
    ROOT/{object}/grasp={g}/augmentation={k}/RGB.pkl            (3, H, W, 3) BGR difference
                                                                images in [0, 1]
                                             RGB_markers.pkl    the same, the marker finger
                                             depth.pkl, depth_markers.pkl   (3, H, W) mm
                                             forces.pkl (3,) N, widths.pkl (3,) m
                                             elastic_estimate.pkl, hertz_estimate.pkl  () Pa
                                                 (absent where the fit failed)
                                             elastic_estimate_rig.pkl, hertz_estimate_rig.pkl
                                                 () Pa, rig-corrected (ours only; absent
                                                 without a rig or where the fit failed)
    ROOT/generation.json                     the generator's manifest (synthetic trees)

See docs/data.md, "Importing the GelSight Young's-modulus dataset".
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Iterable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

from tactile_compliance.data import plausibility
from tactile_compliance.data.image_ops import resize_frames
from tactile_compliance.data.plausibility import PlausibleRange, dtype_problem
from tactile_compliance.data.safe_pickle import (
    ArrayTooLargeError,
    UnsafePickleError,
    dump_numpy_pickle,
    load_numpy_pickle,
)
from tactile_compliance.data.store import FRAMES_PER_SAMPLE
from tactile_compliance.outputs import atomic_file
from tactile_compliance.physics.estimators import DEFAULT_ESTIMATOR, WEDGE_UNITS, GraspUnits

FingerChoice = Literal["markerless", "markers", "both"]

#: Video files (case-insensitive suffixes) that ``import yuan`` and ``predict`` accept.
VIDEO_SUFFIXES = (
    ".avi",
    ".mp4",
    ".mov",
    ".mkv",
    ".m4v",
    ".mpg",
    ".mpeg",
    ".wmv",
    ".webm",
    ".mjpg",
    ".mjpeg",
)
#: finger name -> (image file, depth file)
FINGER_FILES: dict[str, tuple[str, str]] = {
    "markerless": ("RGB.pkl", "depth.pkl"),
    "markers": ("RGB_markers.pkl", "depth_markers.pkl"),
}
FORCES_FILE = "forces.pkl"
WIDTHS_FILE = "widths.pkl"
#: (elastic E, Hertz E*) in Pa; a file is left out where its fit failed, as in the dataset.
ESTIMATE_FILES = ("elastic_estimate.pkl", "hertz_estimate.pkl")
#: The same pair with the rig's own closure taken out (``physics.contact.
#: rig_corrected_widths_m``), at the stiffness the grasp's :data:`UNITS_FILE` names; the
#: public dataset has none, the generator and ``record --rig`` write them.
RIG_ESTIMATE_FILES = ("elastic_estimate_rig.pkl", "hertz_estimate_rig.pkl")
METADATA_FILE = "metadata.json"
#: Written by the generator at the root of a generated tree.
SYNTHETIC_MANIFEST = "generation.json"
UNITS_FILE = "units.json"
"""Written into every grasp directory (``grasp=g/``) by ``record`` and the generator, with
the grasp: the analytical estimator, depth model and pixel density its estimates were made
with (``physics.estimators.GraspUnits``). The public dataset's grasps have none
(:func:`tree_units`)."""
#: The dtypes the writer stores images and depth maps in (forces, widths, estimates: float64).
ALLOWED_DTYPES = ("float16", "float32", "float64")
#: The plausibility rule of each file's values (both fingers' image files: frames).
FILE_RULES: dict[str, PlausibleRange] = {
    FORCES_FILE: plausibility.FORCE,
    WIDTHS_FILE: plausibility.WIDTH,
    **dict.fromkeys(ESTIMATE_FILES, plausibility.ESTIMATE),
    **dict.fromkeys(RIG_ESTIMATE_FILES, plausibility.ESTIMATE),
    **{image_file: plausibility.FRAME for image_file, _ in FINGER_FILES.values()},
}
GRASP_DIR = re.compile(r"^grasp=(\d+)$")
AUGMENTATION_DIR = re.compile(r"^augmentation=(\d+)$")


class SampleError(Exception):
    """One sample cannot be read; the message is the reason (importer and ``predict``)."""


def grasp_dir(object_dir: Path, grasp: int) -> Path:
    """The directory of grasp ``grasp`` of an object."""
    return object_dir / f"grasp={grasp}"


def augmentation_dir(grasp_directory: Path, augmentation: int) -> Path:
    """The sample directory of augmentation ``augmentation`` of a grasp."""
    return grasp_directory / f"augmentation={augmentation}"


def numbered_dirs(parent: Path, pattern: re.Pattern[str]) -> list[tuple[int, Path]]:
    """(number, directory) of the children of ``parent`` named by ``pattern``, sorted.

    Raises:
        OSError: ``parent`` cannot be listed.
    """
    found = [
        (int(match.group(1)), child)
        for child in parent.iterdir()
        if (match := pattern.match(child.name)) and child.is_dir()
    ]
    return sorted(found)


def is_sample_dir(path: Path) -> bool:
    """Whether ``path`` holds a sample's files (forces or an image of either finger)."""
    names = (FORCES_FILE, *(files[0] for files in FINGER_FILES.values()))
    return any((path / name).is_file() for name in names)


def sample_dirs(path: Path) -> list[tuple[int, int, Path]]:
    """(grasp, augmentation, directory) under an augmentation, grasp or object directory.

    A number the path does not name (an augmentation directory outside the layout) is 0.
    """
    if is_sample_dir(path):
        grasp = GRASP_DIR.match(path.parent.name)
        aug = AUGMENTATION_DIR.match(path.name)
        return [(int(grasp.group(1)) if grasp else 0, int(aug.group(1)) if aug else 0, path)]
    augmentations = numbered_dirs(path, AUGMENTATION_DIR)
    if augmentations:
        grasp = GRASP_DIR.match(path.name)
        g = int(grasp.group(1)) if grasp else 0
        return [(g, k, d) for k, d in augmentations if is_sample_dir(d)]
    return [
        (g, k, d)
        for g, grasp_dir in numbered_dirs(path, GRASP_DIR)
        for k, d in numbered_dirs(grasp_dir, AUGMENTATION_DIR)
        if is_sample_dir(d)
    ]


# ---------------------------------------------------------------------- reading
def read_metadata(object_dir: Path) -> dict[str, Any]:
    """An object's ``metadata.json`` as a dict.

    Raises:
        FileNotFoundError: there is none.
        ValueError: it is unreadable, not JSON or not a JSON object.
    """
    path = object_dir / METADATA_FILE
    if not path.is_file():
        raise FileNotFoundError(f"missing file: {METADATA_FILE}")
    try:
        metadata = json.loads(path.read_text(encoding="utf-8"))
    except (ValueError, OSError) as err:  # JSONDecodeError, UnicodeDecodeError
        raise ValueError(f"corrupt {METADATA_FILE}: {err}") from err
    if not isinstance(metadata, dict):
        raise ValueError(f"corrupt {METADATA_FILE}: not a JSON object")
    return metadata


def _implausible(name: str, values: np.ndarray) -> None:
    """SampleError when a value of file ``name`` breaks its plausibility rule (NaN aside)."""
    rule = FILE_RULES.get(name)
    problem = rule.violation(values) if rule is not None else None
    if problem:
        raise SampleError(f"implausible value: {name}: {problem}")


def _load_array(path: Path) -> np.ndarray:
    """A numeric array (integer or float dtype, never cast) from an untrusted pickle, or
    SampleError."""
    if not path.is_file():
        raise SampleError(f"missing file: {path.name}")
    try:
        array = load_numpy_pickle(path)
    except UnsafePickleError as err:
        raise SampleError(f"unsafe pickle rejected: {err}") from err
    except ArrayTooLargeError as err:
        raise SampleError(f"array too large: {path.name} {err}") from err
    except OSError as err:
        raise SampleError(f"unreadable file: {path.name} ({err})") from err
    except Exception as err:  # only numpy code runs: any other error means a bad file
        raise SampleError(f"corrupt pickle: {path.name} ({type(err).__name__}: {err})") from err
    if dtype_problem(array.dtype):
        rule = FILE_RULES.get(path.name)
        unit = f" ({rule.quantity} in {rule.unit})" if rule is not None else ""
        raise SampleError(f"wrong dtype: {path.name} is {array.dtype}, expected numbers{unit}")
    return array


def load_vector(directory: Path, name: str, *, optional: bool = False) -> np.ndarray:
    """A finite float64 vector of one value per frame (forces [N], widths [m]) from a
    pickle, within the file's plausibility rule (:data:`FILE_RULES`); all NaN when the file
    is absent and ``optional``."""
    if optional and not (directory / name).is_file():
        return np.full(FRAMES_PER_SAMPLE, np.nan)
    array = _load_array(directory / name).astype(np.float64)
    if array.shape != (FRAMES_PER_SAMPLE,):
        raise SampleError(
            f"wrong array shape: {name} is {array.shape}, expected ({FRAMES_PER_SAMPLE},)"
        )
    if not np.all(np.isfinite(array)):
        raise SampleError(f"non-finite values: {name}")
    _implausible(name, array)
    return array


def load_estimate(directory: Path, name: str) -> float:
    """An analytical estimate in Pa, or NaN when absent or NaN (a failed fit: the filter
    decides what to drop). Infinite, zero or negative estimates are implausible."""
    if not (directory / name).is_file():
        return float("nan")
    array = _load_array(directory / name)
    if array.size != 1:
        raise SampleError(f"wrong array shape: {name} is {array.shape}, expected a scalar")
    _implausible(name, array)
    return float(array.reshape(()))


def load_frames(directory: Path, name: str, expected_hw: tuple[int, int] | None) -> np.ndarray:
    """Difference images as float32 RGB (3, H, W, 3); the files store BGR. Values must pass
    the frame rule (``plausibility.FRAME``): the store's uint8 encoding would otherwise clip
    them silently."""
    array = _load_array(directory / name)
    if (
        array.ndim != 4
        or array.shape[0] != FRAMES_PER_SAMPLE
        or array.shape[3] != 3
        or array.size == 0
    ):
        raise SampleError(f"wrong array shape: {name} is {array.shape}, expected (3, H, W, 3)")
    if expected_hw is not None and tuple(array.shape[1:3]) != expected_hw:
        raise SampleError(
            f"wrong array shape: {name} is {array.shape}, the dataset's frames are "
            f"{expected_hw[0]}x{expected_hw[1]}"
        )
    if not np.all(np.isfinite(array)):
        raise SampleError(f"non-finite values: {name}")
    _implausible(name, array)
    # Explicit channel flip: the dataset was written by OpenCV (BGR); the store is RGB.
    return np.ascontiguousarray(array[..., ::-1], dtype=np.float32)


def load_depth(
    directory: Path, name: str, depth_size: tuple[int, int] | None
) -> tuple[np.ndarray, np.ndarray | None]:
    """Maximum gel depth of each frame in mm (NaN when the depth file is absent), and the
    depth maps area-averaged to ``depth_size`` (h, w) px as float32 mm (None when the
    file is absent or ``depth_size`` is None: the store keeps no depth)."""
    if not (directory / name).is_file():
        return np.full(FRAMES_PER_SAMPLE, np.nan), None
    depth = _load_array(directory / name)
    if depth.ndim != 3 or depth.shape[0] != FRAMES_PER_SAMPLE or depth.size == 0:
        raise SampleError(f"wrong array shape: {name} is {depth.shape}, expected (3, H, W)")
    if not np.all(np.isfinite(depth)):
        raise SampleError(f"non-finite values: {name}")
    maxima = depth.reshape(FRAMES_PER_SAMPLE, -1).max(axis=1).astype(np.float64)
    if depth_size is None:
        return maxima, None
    return maxima, resize_frames(depth.astype(np.float32), depth_size)


def read_units_file(grasp_directory: Path) -> GraspUnits | None:
    """The units in a grasp directory's :data:`UNITS_FILE`, or None when it has none.

    Raises:
        ValueError: a damaged file, naming it (its estimates' units would be unknown).
    """
    path = Path(grasp_directory) / UNITS_FILE
    if not path.is_file():
        return None
    try:
        return GraspUnits.from_dict(json.loads(path.read_text(encoding="utf-8")))
    except (OSError, ValueError, TypeError) as err:
        raise ValueError(f"{path}: cannot read the grasp's units ({err})") from err


@dataclass(frozen=True)
class TreeUnits:
    """The one set of units of a tree's grasps (:func:`tree_units`).

    Attributes:
        units: what every grasp's estimates are in; its ``rig_stiffness_n_per_m`` is the
            one every grasp names, None when some name another or none (their
            rig-corrected estimates are then not comparable, and not read).
        unnamed: the grasp directories without :data:`UNITS_FILE` (the public dataset's,
            or copied from one), taken to be in ``units`` by the dataset heuristic.
        rig_stiffnesses_n_per_m: every rig stiffness [N/m] the grasps name (None: a grasp
            without rig-corrected estimates), in the order first seen.
    """

    units: GraspUnits
    unnamed: tuple[Path, ...] = ()
    rig_stiffnesses_n_per_m: tuple[float | None, ...] = (None,)

    @property
    def mixed_rigs(self) -> bool:
        """Whether the grasps name more than one rig (or some none): no rig-corrected
        estimates are taken from them."""
        return len(self.rig_stiffnesses_n_per_m) > 1


def tree_units(
    grasp_directories: Iterable[Path], *, unnamed_estimator: str = DEFAULT_ESTIMATOR.name
) -> TreeUnits:
    """The units of a set of grasps, each read from its own :data:`UNITS_FILE` (no
    dataset-wide record, so copying objects between datasets or deleting a file cannot
    relabel another grasp's estimates).

    A grasp without the file is taken, explicitly (:attr:`TreeUnits.unnamed`), to be in
    the public dataset's units: its depth heuristic at the Wedge's pixel density, with
    ``unnamed_estimator`` (a generated tree's manifest names it; else the dataset's own).
    The rig stiffness of the rig-corrected estimates is not part of the comparison: the
    dataset's two estimates of grasps of different rigs (or with none) still mix, and the
    result names a stiffness only when every grasp names the same one.

    Raises:
        ValueError: grasps in two units (one line naming a grasp of each and both units),
            or a damaged file.
    """
    heuristic = GraspUnits(WEDGE_UNITS, unnamed_estimator)
    first: tuple[Path, GraspUnits] | None = None
    unnamed: list[Path] = []
    rigs: dict[float | None, None] = {}
    for directory in dict.fromkeys(Path(d) for d in grasp_directories):  # each grasp once
        own = read_units_file(directory)
        if own is None:
            unnamed.append(directory)
            own = heuristic
        rigs[own.rig_stiffness_n_per_m] = None
        units = replace(own, rig_stiffness_n_per_m=None)
        if first is None:
            first = (directory, units)
        elif units != first[1]:
            named = {first[0]: first[1], directory: units}
            shown = [
                f"{path} has {u.describe()}"
                + (" (no units.json: the dataset's heuristic)" if path in unnamed else "")
                for path, u in named.items()
            ]
            raise ValueError(
                f"grasps in two units: {shown[0]}, {shown[1]}; their estimates cannot be "
                "mixed: keep each sensor's grasps in a dataset of their own"
            )
    stiffnesses = tuple(rigs) or (None,)
    common = stiffnesses[0] if len(stiffnesses) == 1 else None
    units = replace(first[1] if first else heuristic, rig_stiffness_n_per_m=common)
    return TreeUnits(units, tuple(unnamed), stiffnesses)


def sample_grasp_dir(sample_directory: Path) -> Path:
    """The grasp directory of a sample (augmentation) directory: its parent, where
    :data:`UNITS_FILE` lies."""
    return Path(sample_directory).parent


# ---------------------------------------------------------------------- writing
def _write_json(path: Path, data: dict[str, Any]) -> None:
    # Sorted keys, no timestamp: generated trees are byte-identical for the same seed.
    with atomic_file(path, "w") as handle:
        json.dump(data, handle, indent=2, sort_keys=True)
        handle.write("\n")


def write_metadata(
    object_dir: Path,
    name: str,
    modulus_pa: float,
    material: str,
    shape: str,
    shore: tuple[float | None, float | None, float | None],
    **extra: Any,
) -> Path:
    """Write an object's ``metadata.json`` with the dataset's fields.

    Args:
        object_dir: the object's directory.
        name: ``object_name``; modulus_pa: ``youngs_modulus``, Young's modulus E in Pa.
        material, shape: as the dataset names them (``Rubber``, ``Sphere``, ...).
        shore: Shore 00, A and D hardness, None where not measured.
        extra: further fields (the generator's ``used_in_training``).
    """
    path = object_dir / METADATA_FILE
    shore_00, shore_a, shore_d = shore
    metadata = {
        "object_name": name,
        "youngs_modulus": float(modulus_pa),
        "material": material,
        "shape": shape,
        "shore_00_hardness": shore_00,
        "shore_A_hardness": shore_a,
        "shore_D_hardness": shore_d,
        **extra,
    }
    _write_json(path, metadata)
    return path


def write_units_file(grasp_directory: Path, units: GraspUnits) -> Path:
    """Write a grasp's :data:`UNITS_FILE` (into the caller's temporary grasp or object
    directory, so the grasp and its units are committed together)."""
    path = Path(grasp_directory) / UNITS_FILE
    path.parent.mkdir(parents=True, exist_ok=True)
    _write_json(path, units.to_dict())
    return path


def write_sample(
    directory: Path,
    fingers: dict[str, tuple[np.ndarray, np.ndarray]],
    forces_n: np.ndarray,
    widths_m: np.ndarray,
    estimates_pa: tuple[float, float],
    dtype: str = "float32",
    rig_estimates_pa: tuple[float, float] | None = None,
) -> None:
    """Write one ``grasp=g/augmentation=k`` directory (created; its parents too).

    Args:
        directory: the sample directory (:func:`augmentation_dir`), inside the caller's
            temporary directory: the caller commits the whole object or grasp at once.
        fingers: finger name (:data:`FINGER_FILES`) -> (BGR difference images
            (3, H, W, 3) in [0, 1], depth maps (3, H, W) in mm).
        forces_n: (3,) gripper force in N; widths_m: (3,) gripper width in m.
        estimates_pa: (elastic E, Hertz E*) in Pa; a non-finite one gets no file.
        rig_estimates_pa: the rig-corrected pair in Pa (:data:`RIG_ESTIMATE_FILES`, the
            stiffness in the grasp's units); None or a non-finite one: no file.
        dtype: of the images and depth maps (:data:`ALLOWED_DTYPES`); float16 halves a
            tree and keeps a difference image well inside half a grey level.
    """
    if dtype not in ALLOWED_DTYPES:
        raise ValueError(f"dtype must be one of {ALLOWED_DTYPES}, got {dtype!r}")
    directory.mkdir(parents=True)
    for finger, (images, depths) in fingers.items():
        image_file, depth_file = FINGER_FILES[finger]
        dump_numpy_pickle(directory / image_file, np.asarray(images).astype(dtype))
        dump_numpy_pickle(directory / depth_file, np.asarray(depths).astype(dtype))
    dump_numpy_pickle(directory / FORCES_FILE, np.asarray(forces_n, dtype=np.float64))
    dump_numpy_pickle(directory / WIDTHS_FILE, np.asarray(widths_m, dtype=np.float64))
    named = list(zip(ESTIMATE_FILES, estimates_pa, strict=True))
    if rig_estimates_pa is not None:
        named += zip(RIG_ESTIMATE_FILES, rig_estimates_pa, strict=True)
    for name, value in named:
        if math.isfinite(value):  # the dataset has no file for a failed fit
            dump_numpy_pickle(directory / name, np.array(value, dtype=np.float64))
