"""The model-free estimate on real grasps: ``estimate`` against the true moduli.

Every recording ``<stem>.avi`` with its ``<stem>_readings.csv`` under ``--recordings``
goes through the two commands a user runs, called in-process through the CLI (the
helpers of ``benchmarks/real_grasps.py``: the same recordings, corners and labels):

1. ``calibrate wedge:VIDEO --corners ... --warp-size 300x400 --frames 3``;
2. ``estimate wedge:VIDEO --calibration CAL --readings CSV --rig wedge-2023 --json``.

The rig-corrected estimates use the packaged ``wedge-2023`` rig (``--rig``), whose
stiffness ``calibrate-rig`` fitted on the golf ball's three grasps, which are among
these recordings (docs/results.md, "What was fitted on what").

Reported: per object the true E and the geometric mean of each estimate over its grasps,
and per estimate the share of grasps within one decade of the truth, the N-MSE, the MAE
in decades and Spearman's rank correlation (``real_grasps.score``). The numbers that
``estimate`` quotes (``acquisition.estimates.REAL_WEDGE_ACCURACY``) are this run's on the
15 grasps of ``../shared/reference-data/real/wedge-grasps`` (5 objects);
``tests/test_estimate.py`` runs it and fails when they no longer hold.

Run (0.5-1 min on the shared 2-core project machine)::

    python benchmarks/real_estimates.py
    python benchmarks/real_estimates.py --json real_estimates.json

A research script, not part of the installed package.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))

import real_grasps

ESTIMATES = ("elastic", "hertz", "elastic_rig", "hertz_rig")
RIG = "wedge-2023"


def run(
    recordings: Path = real_grasps.DEFAULT_RECORDINGS,
    objects: Path = real_grasps.DEFAULT_OBJECTS,
    *,
    frames: int = 3,
    warp_size: str = "300x400",
    log: Any = print,
) -> dict[str, Any]:
    """Calibrate and estimate every recording; the scores (see the module docstring)."""
    from tactile_compliance.data.object_table import read_object_table

    started = time.perf_counter()
    pairs = real_grasps.find_recordings(Path(recordings))
    corners = real_grasps.read_corners(Path(recordings))
    if corners is None:
        raise real_grasps.BenchmarkError(f"{recordings}: no wedge_config/config_*.csv")
    table = read_object_table(objects)
    stems = [video.stem for video, _ in pairs]
    matched = real_grasps.match_labels(
        stems, list(table.index), real_grasps.readme_labels(Path(recordings)), {}
    )
    grasps: list[dict[str, Any]] = []
    commands: list[str] = []
    with tempfile.TemporaryDirectory(prefix="real-estimates-") as work:
        for (video, readings), stem in zip(pairs, stems, strict=True):
            calibration = Path(work) / f"{stem}.json"
            spec = f"wedge:{video}"
            calibrate = ["calibrate", spec, "--out", calibration, "--corners", corners]
            calibrate += ["--warp-size", warp_size, "--frames", frames]
            real_grasps.run_cli(*calibrate)
            estimate = ["estimate", spec, "--calibration", calibration, "--readings", readings]
            estimate += ["--rig", RIG]
            commands.append("tactile-compliance " + " ".join(map(str, estimate)))
            result = json.loads(real_grasps.run_cli(*estimate, "--json"))
            label = matched[stem]
            grasps.append(
                {
                    "recording": stem,
                    "object": label,
                    "true_pa": float(table.loc[label]["modulus_pa"]),
                    "elastic": result["elastic_pa"],
                    "hertz": result["hertz_pa"],
                    "elastic_rig": result["rig_corrected_pa"][0],
                    "hertz_rig": result["rig_corrected_pa"][1],
                    "frame_indices": result["frame_indices"],
                }
            )
            log(f"{stem}: elastic {result['elastic_pa']}, Hertz {result['hertz_pa']}")
    return {
        "recordings": str(recordings),
        "n_grasps": len(grasps),
        "n_objects": len({g["object"] for g in grasps}),
        "estimators": list(ESTIMATES),
        "names": {
            "elastic": "elastic (estimate)",
            "hertz": "Hertz (estimate)",
            "elastic_rig": f"elastic, rig-corrected ({RIG})",
            "hertz_rig": f"Hertz, rig-corrected ({RIG})",
        },
        "grasps": grasps,
        "objects": real_grasps.per_object(grasps, ESTIMATES),
        "summary": {key: real_grasps.score(grasps, key) for key in ESTIMATES},
        "commands": commands,
        "seconds": time.perf_counter() - started,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--recordings", type=Path, default=real_grasps.DEFAULT_RECORDINGS)
    parser.add_argument("--objects", type=Path, default=real_grasps.DEFAULT_OBJECTS)
    parser.add_argument("--json", type=Path, help="write every number to this file")
    args = parser.parse_args(argv)
    try:
        result = run(args.recordings, args.objects)
    except real_grasps.BenchmarkError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(real_grasps.format_tables(result))
    print(
        f"{result['n_grasps']} grasps of {result['n_objects']} objects, {result['seconds']:.0f} s"
    )
    if args.json is not None:
        args.json.write_text(json.dumps(result, indent=2), encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
