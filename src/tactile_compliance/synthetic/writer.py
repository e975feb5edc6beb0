"""Write simulated objects in the raw layout of the GelSight Young's-modulus dataset.

::

    OUT/{object}/metadata.json
    OUT/{object}/grasp={g}/augmentation={k}/RGB.pkl            (3, H, W, 3) BGR difference images
                                            RGB_markers.pkl    same, marker finger
                                            depth.pkl          (3, H, W) mm
                                            depth_markers.pkl  same, marker finger
                                            forces.pkl         (3,) N, float64
                                            widths.pkl         (3,) m, float64
                                            elastic_estimate.pkl  0-d float64, Pa
                                            hertz_estimate.pkl    0-d float64, Pa (E*)

Every ``.pkl`` is a pickled numpy array (protocol 4: same bytes for the same array).
Images and depth maps are stored as ``dtype`` (float16 by default: the difference
images are multiples of 1/255 offset by 0.5, which float16 represents to 2.4e-4, well
inside half a grey level, and it halves a full-size tree to ~4.2 MB per sample
directory; use float32 or float64 - what the real files hold - for byte-size fidelity).

An object is written into a hidden ``.partial-{object}`` directory and renamed into
place only when complete, so an interrupted run never leaves a half-written object
that looks finished (and importers skip hidden directories).
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np

from tactile_compliance.data.safe_pickle import PICKLE_PROTOCOL, dump_numpy_pickle
from tactile_compliance.synthetic.grasp import GraspSample
from tactile_compliance.synthetic.objects import ObjectSpec

__all__ = ["PARTIAL_PREFIX", "PICKLE_PROTOCOL", "ObjectWriter", "metadata_dict"]

PARTIAL_PREFIX = ".partial-"
ALLOWED_DTYPES = ("float16", "float32", "float64")


def metadata_dict(spec: ObjectSpec) -> dict[str, object]:
    """The ``metadata.json`` fields of the real dataset for an object."""
    return {
        "object_name": spec.name,
        "youngs_modulus": float(spec.modulus_pa),
        "material": spec.material,
        "shape": spec.shape,
        "shore_00_hardness": spec.shore_00,
        "shore_A_hardness": spec.shore_a,
        "shore_D_hardness": spec.shore_d,
        "used_in_training": bool(spec.used_in_training),
    }


_dump = dump_numpy_pickle


class ObjectWriter:
    """Streams one object's grasps into a partial directory, then commits it."""

    def __init__(self, out_dir: Path, spec: ObjectSpec, dtype: str = "float16") -> None:
        if dtype not in ALLOWED_DTYPES:
            raise ValueError(f"dtype must be one of {ALLOWED_DTYPES}, got {dtype!r}")
        self.final = out_dir / spec.name
        self.partial = out_dir / f"{PARTIAL_PREFIX}{spec.name}"
        self.dtype = np.dtype(dtype)
        if self.partial.exists():
            shutil.rmtree(self.partial)
        self.partial.mkdir(parents=True)
        text = json.dumps(metadata_dict(spec), indent=2, sort_keys=True) + "\n"
        (self.partial / "metadata.json").write_text(text)
        self.samples = 0

    def add_grasp(self, grasp: int, samples: list[GraspSample]) -> None:
        """Write ``grasp={grasp}/augmentation={k}`` for each sample k."""
        for k, sample in enumerate(samples):
            directory = self.partial / f"grasp={grasp}" / f"augmentation={k}"
            directory.mkdir(parents=True)
            _dump(directory / "RGB.pkl", sample.rgb.astype(self.dtype))
            _dump(directory / "depth.pkl", sample.depth.astype(self.dtype))
            _dump(directory / "RGB_markers.pkl", sample.rgb_markers.astype(self.dtype))
            _dump(directory / "depth_markers.pkl", sample.depth_markers.astype(self.dtype))
            _dump(directory / "forces.pkl", np.asarray(sample.forces, dtype=np.float64))
            _dump(directory / "widths.pkl", np.asarray(sample.widths, dtype=np.float64))
            _dump(
                directory / "elastic_estimate.pkl",
                np.array(sample.elastic_estimate, dtype=np.float64),
            )
            _dump(
                directory / "hertz_estimate.pkl", np.array(sample.hertz_estimate, dtype=np.float64)
            )
            self.samples += 1

    def commit(self) -> Path:
        """Rename the finished object into place (replacing nothing: it must not exist)."""
        if self.final.exists():
            raise FileExistsError(f"{self.final} already exists")
        os.replace(self.partial, self.final)
        return self.final

    def abort(self) -> None:
        """Remove the partial directory."""
        shutil.rmtree(self.partial, ignore_errors=True)
