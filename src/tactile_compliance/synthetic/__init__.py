"""Physically grounded synthetic GelSight grasps: the project's default dataset and fixture.

:func:`generate_burgess_tree` writes the Young's-modulus dataset's raw layout,
:func:`generate_shore_videos` Shore-hardness press videos, :func:`render_montage` the
documentation montage. See docs/synthetic.md.
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
