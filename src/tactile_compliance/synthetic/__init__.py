"""Physically grounded synthetic GelSight grasps: the project's default dataset and fixture.

* :func:`generate_burgess_tree` writes the raw layout of the GelSight Young's-modulus
  dataset (per-object ``metadata.json``, ``grasp=g/augmentation=k/*.pkl``), so the
  Burgess importer runs on it unchanged.
* :func:`generate_shore_videos` writes press videos named like the Shore-hardness
  dataset (``{SHAPE}_{hardness:02d}_{n}.avi``) for the Yuan importer.
* :func:`render_montage` draws the documentation montage.

Physics and parameters: ``docs/synthetic.md`` and the module docstrings
(``mechanics``, ``timeseries``, ``render``, ``materials``, ``geometry``; the photometric
  depth reconstruction is ``data.photometric``, shared with recorded real grasps).
"""

from typing import Any

from tactile_compliance.synthetic.generate import (
    DEFAULT_N_OBJECTS,
    GenerationError,
    GenerationReport,
    generate_burgess_tree,
)

__all__ = [
    "DEFAULT_N_OBJECTS",
    "GenerationError",
    "GenerationReport",
    "generate_burgess_tree",
    "generate_shore_videos",
    "render_montage",
]


def __getattr__(name: str) -> Any:
    # Lazy: these modules are also run as scripts (``python -m ...montage``), which must
    # not find them already imported by the package.
    if name == "render_montage":
        from tactile_compliance.synthetic.montage import render_montage

        return render_montage
    if name == "generate_shore_videos":
        from tactile_compliance.synthetic.shore_videos import generate_shore_videos

        return generate_shore_videos
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
