"""The four input strategies of the paper (Image, ImageF, ImageFW, ALL): which scalar
inputs a model sees besides the frames. See docs/models.md, "Input strategies".
"""

from __future__ import annotations

from enum import Enum


class InputStrategy(str, Enum):
    """Which inputs a model uses besides the tactile frames; the values are the paper's
    names, so they go straight into reports and configuration files."""

    IMAGE = "Image"
    IMAGE_F = "ImageF"
    IMAGE_FW = "ImageFW"
    ALL = "ALL"

    @property
    def uses_force(self) -> bool:
        """Whether the normal force F (3 values per sample) is an input."""
        return self is not InputStrategy.IMAGE

    @property
    def uses_width(self) -> bool:
        """Whether the gripper width W (3 values per sample) is an input."""
        return self in (InputStrategy.IMAGE_FW, InputStrategy.ALL)

    @property
    def uses_estimates(self) -> bool:
        """Whether the two analytical estimates E (elastic, Hertz) are an input."""
        return self is InputStrategy.ALL

    @property
    def needs(self) -> tuple[str, ...]:
        """The scalar inputs this strategy uses: a subset of ("force", "width", "estimates")."""
        flags = (
            ("force", self.uses_force),
            ("width", self.uses_width),
            ("estimates", self.uses_estimates),
        )
        return tuple(name for name, used in flags if used)

    @classmethod
    def names(cls) -> tuple[str, ...]:
        """The paper's names in its table order: ("Image", "ImageF", "ImageFW", "ALL")."""
        return tuple(member.value for member in cls)

    @classmethod
    def parse(cls, value: InputStrategy | str) -> InputStrategy:
        """A member, its value or its member name, in any case and with ``_``/``-`` ignored
        ("image_fw"): the names arrive from the command line and YAML files, where the
        paper's capitalisation is easy to miss. ValueError lists the valid names."""
        if isinstance(value, cls):
            return value
        if not isinstance(value, str):
            raise ValueError(
                f"input strategy must be a string, got {type(value).__name__}: {value!r}; "
                f"valid names: {', '.join(m.value for m in cls)}"
            )
        key = value.strip().replace("_", "").replace("-", "").lower()
        for member in cls:
            if key in (member.value.lower(), member.name.replace("_", "").lower()):
                return member
        raise ValueError(
            f"unknown input strategy {value!r}; valid names (case-insensitive): "
            f"{', '.join(m.value for m in cls)}"
        )

    def __str__(self) -> str:
        # The paper's spelling, so f-strings and reports show "ImageFW", not the enum repr.
        return self.value
