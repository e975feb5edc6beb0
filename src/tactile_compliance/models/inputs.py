"""The four input strategies of the paper (Image, ImageF, ImageFW, ALL).

Every model takes the three tactile frames; the strategy decides which of the scalar
inputs (normal force F, gripper width W, analytical estimates E) the model also sees.
A disabled input is absent from the model: it has no parameters and no path to the
output (the published code fed zero tensors through live weights instead).
"""

from __future__ import annotations

from enum import Enum


class InputStrategy(str, Enum):
    """Which inputs a model uses besides the tactile frames.

    The values are the names the paper uses in its tables, so ``str(strategy.value)``
    can go straight into reports and configuration files.
    """

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
        """Turn a user-supplied name into a strategy.

        Accepts a member, its value or its member name in any case and with ``_``/``-``
        ignored ("image", "ImageFW", "image_fw", "all"), because these names arrive from
        the command line and YAML files where the paper's capitalisation is easy to miss.

        Raises:
            ValueError: for an unknown name; the message lists the valid names.
        """
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
