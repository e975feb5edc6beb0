"""The object table of the GelSight Young's-modulus dataset (`dataset_objects_and_compliance.csv`).

One row per object with the real column names (``Label``, ``Shape``, ``Material``,
``Modulus [Pa]``, Shore hardness columns, ...). ``Label`` is the object's directory
name in the dataset and ``Modulus [Pa]`` its ground-truth Young's modulus.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from tactile_compliance.data.import_report import DataImportError

LABEL_COLUMN = "Label"
SHAPE_COLUMN = "Shape"
MATERIAL_COLUMN = "Material"
MODULUS_COLUMN = "Modulus [Pa]"
REQUIRED_COLUMNS = (LABEL_COLUMN, SHAPE_COLUMN, MATERIAL_COLUMN, MODULUS_COLUMN)
OPTIONAL_COLUMNS = {
    "Shore 00 [/]": "shore_00",
    "Shore A [/]": "shore_a",
    "Shore D [/]": "shore_d",
    "Radius [m]": "radius_m",
    "Trials Recorded?": "trials_recorded",
}


class ObjectTableError(DataImportError, ValueError):
    """The object table is missing, unreadable (empty, not CSV, not UTF-8, a directory,
    no permission) or does not have the expected columns. Raised before an import writes
    anything; a :class:`DataImportError` and a ``ValueError``."""


def read_object_table(path: str | Path) -> pd.DataFrame:
    """Read the object table into a frame indexed by object name.

    Returns columns ``shape``, ``material``, ``modulus_pa`` (NaN when empty or not a
    number) and, when present, ``shore_00``, ``shore_a``, ``shore_d``, ``radius_m``,
    ``trials_recorded``.
    """
    path = Path(path)
    if not path.is_file():
        raise ObjectTableError(f"{path}: object table not found")
    try:
        raw = pd.read_csv(path)
    except pd.errors.EmptyDataError as err:
        raise ObjectTableError(f"{path}: the object table is empty") from err
    except (pd.errors.ParserError, UnicodeDecodeError, ValueError) as err:
        raise ObjectTableError(f"{path}: cannot parse CSV ({err})") from err
    except OSError as err:
        raise ObjectTableError(f"{path}: cannot read the object table ({err})") from err
    raw.columns = [str(c).strip() for c in raw.columns]
    missing = [c for c in REQUIRED_COLUMNS if c not in raw.columns]
    if missing:
        raise ObjectTableError(
            f"{path}: missing column(s) {missing}; expected the dataset's columns "
            f"{list(REQUIRED_COLUMNS)}"
        )
    table = pd.DataFrame(
        {
            "object": raw[LABEL_COLUMN].astype(str).str.strip(),
            "shape": raw[SHAPE_COLUMN].fillna("").astype(str).str.strip(),
            "material": raw[MATERIAL_COLUMN].fillna("").astype(str).str.strip(),
            "modulus_pa": pd.to_numeric(raw[MODULUS_COLUMN], errors="coerce"),
        }
    )
    for source, target in OPTIONAL_COLUMNS.items():
        if source in raw.columns:
            table[target] = (
                raw[source]
                if target == "trials_recorded"
                else pd.to_numeric(raw[source], errors="coerce")
            )
    duplicated = table["object"][table["object"].duplicated()].tolist()
    if duplicated:
        raise ObjectTableError(f"{path}: duplicated labels {duplicated[:5]}")
    return table.set_index("object")


def valid_modulus(value: object) -> bool:
    """A usable ground-truth modulus: a finite number > 0 Pa."""
    try:
        number = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return False
    return bool(np.isfinite(number) and number > 0)
