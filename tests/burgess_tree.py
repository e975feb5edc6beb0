"""Write small trees in the exact layout of the GelSight Young's-modulus dataset (numpy + pickle).

Used by the importer tests and the import benchmark; deliberately independent of the
project's synthetic generator so that the importer is checked against the layout itself.
"""

from __future__ import annotations

import json
import pickle
from pathlib import Path

import numpy as np

OBJECTS = {
    # name: (modulus Pa, material, shape)
    "foam_block": (2.0e4, "Foam", "Rectangular"),
    "rubber_ball": (8.0e5, "Rubber", "Sphere"),
    "steel_rod": (2.0e11, "Metal", "Cylinder"),
}


def dump(path: Path, array: object) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(pickle.dumps(array, protocol=4))


def sample_values(
    seed: int, size: tuple[int, int] = (12, 16), dtype: type = np.float64
) -> dict[str, np.ndarray]:
    """Deterministic arrays of one augmentation directory (BGR images, depth in mm)."""
    rng = np.random.default_rng(seed)
    h, w = size
    return {
        "RGB.pkl": (0.5 + 0.05 * rng.standard_normal((3, h, w, 3), dtype=np.float32)).astype(dtype),
        "RGB_markers.pkl": (
            0.5 + 0.05 * rng.standard_normal((3, h, w, 3), dtype=np.float32)
        ).astype(dtype),
        "depth.pkl": np.abs(rng.standard_normal((3, h, w)))
        * np.array([0.5, 1.0, 1.5])[:, None, None],
        "depth_markers.pkl": np.abs(rng.standard_normal((3, h, w))),
        "forces.pkl": np.array([10.0, 30.0, 55.0]) + rng.uniform(0, 1, 3),
        "widths.pkl": np.array([0.050, 0.048, 0.047]) - rng.uniform(0, 1e-4, 3),
        "elastic_estimate.pkl": np.array(rng.uniform(1e4, 1e6)),
        "hertz_estimate.pkl": np.array(rng.uniform(1e4, 1e6)),
    }


def write_tree(
    root: Path,
    objects: dict[str, tuple[float, str, str]] = OBJECTS,
    grasps: int = 2,
    augmentations: int = 2,
    size: tuple[int, int] = (12, 16),
    metadata: bool = True,
    dtype: type = np.float64,
    keep: bool = True,
) -> dict[tuple[str, int, int], dict[str, np.ndarray]]:
    """Write the tree; return the arrays written, keyed by (object, grasp, augmentation)
    (an empty dict when ``keep`` is False, for large benchmark trees)."""
    written = {}
    for index, (name, (modulus, material, shape)) in enumerate(objects.items()):
        object_dir = root / name
        object_dir.mkdir(parents=True, exist_ok=True)
        if metadata:
            (object_dir / "metadata.json").write_text(
                json.dumps(
                    {
                        "object_name": name,
                        "youngs_modulus": modulus,
                        "material": material,
                        "shape": shape,
                        "shore_00_hardness": None,
                        "shore_A_hardness": None,
                        "shore_D_hardness": None,
                        "used_in_training": True,
                    }
                )
            )
        for g in range(grasps):
            for k in range(augmentations):
                values = sample_values(1000 * index + 10 * g + k, size, dtype)
                for file_name, array in values.items():
                    dump(object_dir / f"grasp={g}" / f"augmentation={k}" / file_name, array)
                if keep:
                    written[(name, g, k)] = values
    return written
