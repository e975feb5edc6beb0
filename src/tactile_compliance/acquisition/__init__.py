"""Acquisition: frames from a sensor, its calibration, and recording grasps to disk
(``live``, ``calibrate``, ``calibrate-depth``, ``depth``, ``record``). See docs/sensors.md
and docs/inference.md.

The names below load on first use (PEP 562): the command line reads the table of sensors
(``acquisition.sensors.SENSORS``) for its help without loading the recorder, pandas or the
calibration.
"""

from __future__ import annotations

import importlib
from typing import Any

#: Public name -> the module of this package that defines it.
_LAZY = {
    "ObjectInfo": "recording",
    "Readings": "readings",
    "SensorCalibration": "calibration",
    "open_source": "sensors",
    "record_grasp": "recording",
}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"{__name__}.{module}"), name)
    globals()[name] = value
    return value


__all__ = ["ObjectInfo", "Readings", "SensorCalibration", "open_source", "record_grasp"]
