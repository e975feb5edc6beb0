"""Write simulated objects in the raw layout of the GelSight Young's-modulus dataset
(:mod:`~tactile_compliance.data.raw_layout` writes the files).

Images and depth maps are stored as ``dtype`` (float16 by default: the difference
images are multiples of 1/255 offset by 0.5, which float16 represents to 2.4e-4, well
inside half a grey level, and it halves a full-size tree to ~4.2 MB per sample
directory; use float32 or float64 - what the real files hold - for byte-size fidelity).
Every ``.pkl`` is protocol 4: the same bytes for the same array.

An object is written into a hidden ``.partial-{object}`` directory and renamed into
place only when complete, so an interrupted run never leaves a half-written object
that looks finished (and importers skip hidden directories).
"""

from __future__ import annotations

import shutil
from pathlib import Path

from tactile_compliance.data.raw_layout import (
    ALLOWED_DTYPES,
    augmentation_dir,
    grasp_dir,
    write_metadata,
    write_sample,
)
from tactile_compliance.outputs import PARTIAL_PREFIX, commit_path
from tactile_compliance.synthetic.grasp import GraspSample
from tactile_compliance.synthetic.objects import ObjectSpec

__all__ = ["ObjectWriter"]


class ObjectWriter:
    """Streams one object's grasps into a partial directory, then commits it."""

    def __init__(self, out_dir: Path, spec: ObjectSpec, dtype: str = "float16") -> None:
        if dtype not in ALLOWED_DTYPES:
            raise ValueError(f"dtype must be one of {ALLOWED_DTYPES}, got {dtype!r}")
        self.final = out_dir / spec.name
        self.partial = out_dir / f"{PARTIAL_PREFIX}{spec.name}"
        self.dtype = dtype
        if self.partial.exists():
            shutil.rmtree(self.partial)
        self.partial.mkdir(parents=True)
        write_metadata(
            self.partial,
            spec.name,
            spec.modulus_pa,
            spec.material,
            spec.shape,
            (spec.shore_00, spec.shore_a, spec.shore_d),
            used_in_training=bool(spec.used_in_training),
        )
        self.samples = 0

    def add_grasp(self, grasp: int, samples: list[GraspSample]) -> None:
        """Write ``grasp={grasp}/augmentation={k}`` for each sample k."""
        for k, sample in enumerate(samples):
            fingers = {
                "markerless": (sample.rgb, sample.depth),
                "markers": (sample.rgb_markers, sample.depth_markers),
            }
            estimates = (sample.elastic_estimate, sample.hertz_estimate)
            directory = augmentation_dir(grasp_dir(self.partial, grasp), k)
            write_sample(directory, fingers, sample.forces, sample.widths, estimates, self.dtype)
            self.samples += 1

    def commit(self) -> Path:
        """Rename the finished object into place (replacing nothing: it must not exist)."""
        commit_path(self.partial, self.final)
        return self.final

    def abort(self) -> None:
        """Remove the partial directory."""
        shutil.rmtree(self.partial, ignore_errors=True)
