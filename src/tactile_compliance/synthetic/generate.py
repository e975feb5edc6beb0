"""Generate a synthetic dataset in the raw GelSight Young's-modulus layout, resumably.

See docs/synthetic.md, "Usage" (determinism, resume, layout and the float16 choice).
"""

from __future__ import annotations

import json
import os
import shutil
import time
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import asdict, dataclass, field, fields, replace
from multiprocessing import get_context
from pathlib import Path
from typing import Any

from tactile_compliance.data.raw_layout import (
    ALLOWED_DTYPES,
    SYNTHETIC_MANIFEST,
    augmentation_dir,
    grasp_dir,
    write_metadata,
    write_sample,
    write_units_file,
)
from tactile_compliance.outputs import PARTIAL_PREFIX, atomic_file, claim_output_dir, commit_path
from tactile_compliance.physics.estimators import DATASET_UNITS, DEFAULT_ESTIMATOR
from tactile_compliance.synthetic.grasp import (
    SimulationOptions,
    make_context,
    simulate_grasp,
)
from tactile_compliance.synthetic.objects import (
    ObjectSpec,
    default_objects,
    objects_from_table,
)
from tactile_compliance.synthetic.rig import resolve_rig

__all__ = ["DEFAULT_N_OBJECTS", "GenerationError", "GenerationReport", "generate_burgess_tree"]

DEFAULT_N_OBJECTS = 286
"""Objects in the default mix: as many as the real table has labelled objects."""

FORMAT = "tactile-compliance synthetic burgess tree, v1"


class GenerationError(ValueError):
    """Bad generation arguments or an output directory that cannot be resumed."""


@dataclass
class GenerationReport:
    """What a generation run did.

    Attributes:
        out_dir: the dataset directory.
        objects_total: objects in the requested dataset.
        objects_written: objects simulated and written by this run.
        objects_existing: complete objects found and kept (resume).
        grasps: grasps simulated by this run.
        grasps_rejected: grasps the published selection rules rejected (no directory).
        samples: ``grasp=g/augmentation=k`` directories written by this run.
        seconds: wall-clock time of the run [s].
        workers: worker processes used.
        skipped_rows: object-table rows that could not be simulated, with reasons.
    """

    out_dir: Path
    objects_total: int = 0
    objects_written: int = 0
    objects_existing: int = 0
    grasps: int = 0
    grasps_rejected: int = 0
    samples: int = 0
    seconds: float = 0.0
    workers: int = 1
    skipped_rows: list[str] = field(default_factory=list)

    @property
    def grasps_per_second(self) -> float:
        """Simulated grasps per second of wall-clock time."""
        return self.grasps / self.seconds if self.seconds > 0 else 0.0

    @property
    def samples_per_second(self) -> float:
        """Sample directories per second of wall-clock time."""
        return self.samples / self.seconds if self.seconds > 0 else 0.0

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly summary."""
        data = asdict(self)
        data["out_dir"] = str(self.out_dir)
        data["grasps_per_second"] = round(self.grasps_per_second, 3)
        data["samples_per_second"] = round(self.samples_per_second, 3)
        return data

    def format(self) -> str:
        """One human-readable paragraph."""
        lines = [
            f"synthetic dataset: {self.out_dir}",
            f"  objects: {self.objects_written} written, {self.objects_existing} already "
            f"complete, {self.objects_total} in total",
            f"  grasps: {self.grasps} simulated ({self.grasps_rejected} rejected by the "
            f"frame-selection rules); samples written: {self.samples}",
            f"  time: {self.seconds:.1f} s with {self.workers} worker(s) = "
            f"{self.grasps_per_second:.2f} grasps/s, {self.samples_per_second:.2f} samples/s",
        ]
        if self.skipped_rows:
            lines.append(f"  table rows skipped: {len(self.skipped_rows)}")
            lines.extend(f"    {reason}" for reason in self.skipped_rows[:20])
        return "\n".join(lines)


@dataclass(frozen=True)
class _Job:
    spec: ObjectSpec
    seed: int
    options: SimulationOptions
    dtype: str
    out_dir: Path


def _run_object(job: _Job) -> tuple[int, int, int]:
    """Simulate and write one object atomically; returns (grasps, rejected, samples)."""
    spec = job.spec
    ctx = make_context(spec, job.seed, job.options)
    partial = job.out_dir / f"{PARTIAL_PREFIX}{spec.name}"
    if partial.exists():
        shutil.rmtree(partial)
    partial.mkdir(parents=True)
    shore = (spec.shore_00, spec.shore_a, spec.shore_d)
    write_metadata(
        partial,
        spec.name,
        spec.modulus_pa,
        spec.material,
        spec.shape,
        shore,
        used_in_training=bool(spec.used_in_training),
    )
    rejected = samples = 0
    units = replace(DATASET_UNITS, rig_stiffness_n_per_m=job.options.rig.stiffness_n_per_m)
    try:
        for g in range(spec.n_grasps):
            result = simulate_grasp(ctx, g)
            if not result.samples:
                rejected += 1
            else:  # the manifest's estimator on the Wedge's units (as the dataset), and
                # the rig stiffness of the rig-corrected estimates
                write_units_file(grasp_dir(partial, g), units)
            for k, sample in enumerate(result.samples):
                fingers = {
                    "markerless": (sample.rgb, sample.depth),
                    "markers": (sample.rgb_markers, sample.depth_markers),
                }
                estimates = (sample.elastic_estimate, sample.hertz_estimate)
                directory = augmentation_dir(grasp_dir(partial, g), k)
                write_sample(
                    directory,
                    fingers,
                    sample.forces,
                    sample.widths,
                    estimates,
                    job.dtype,
                    rig_estimates_pa=sample.rig_estimates,
                )
                samples += 1
        commit_path(partial, job.out_dir / spec.name)
    except BaseException:
        shutil.rmtree(partial, ignore_errors=True)
        raise
    return spec.n_grasps, rejected, samples


def _split_options(options: dict[str, Any]) -> tuple[SimulationOptions, str, int | None]:
    opts = dict(options)
    dtype = str(opts.pop("dtype", "float16"))
    if dtype not in ALLOWED_DTYPES:
        raise GenerationError(f"dtype must be one of {ALLOWED_DTYPES}, got {dtype!r}")
    workers = opts.pop("workers", None)
    known = {f.name for f in fields(SimulationOptions)} - {"image_size"}
    unknown = sorted(set(opts) - known)
    if unknown:
        raise GenerationError(
            f"unknown option(s) {unknown}; known: {sorted(known | {'dtype', 'workers'})}"
        )
    if isinstance(opts.get("rig"), (str, Path)):
        try:
            opts["rig"] = resolve_rig(opts["rig"])[1]
        except ValueError as err:
            raise GenerationError(str(err)) from err
    return SimulationOptions(**opts), dtype, workers


def _check_manifest(out_dir: Path, manifest: dict[str, Any]) -> None:
    path = out_dir / SYNTHETIC_MANIFEST
    if not path.is_file():
        return
    try:
        existing = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise GenerationError(
            f"{path}: unreadable ({err}); remove it or use a new directory"
        ) from err
    keys = ("format", "seed", "source", "image_size", "options", "dtype", "grasps_per_object")
    different = [k for k in keys if existing.get(k) != manifest.get(k)]
    if different:
        raise GenerationError(
            f"{out_dir} holds a synthetic dataset generated with different parameters "
            f"({', '.join(different)}); resume with the same parameters or use a new directory"
        )


def generate_burgess_tree(
    out_dir: str | Path,
    *,
    n_objects: int | None = None,
    object_table: str | Path | None = None,
    grasps_per_object: int | None = None,
    seed: int = 0,
    image_size: tuple[int, int] = (250, 350),
    progress: bool = True,
    **options: Any,
) -> GenerationReport:
    """Write a synthetic dataset in the raw GelSight Young's-modulus layout.

    An object's files depend only on (seed, object name, options): the same seed gives
    byte-identical files whatever the worker count, and a subset of the objects gives
    exactly the same objects. Each object is written under a hidden ``.partial-NAME``
    and renamed into place when complete; a re-run keeps complete objects and redoes the
    rest, and one with other parameters is refused (``generation.json``).

    Args:
        out_dir: output directory (created; complete objects already there are kept).
        n_objects: number of objects of the default mix (default 286, like the real
            table); cannot be combined with ``object_table``.
        object_table: a table in the real CSV format; one object per row with a valid
            ``Modulus [Pa]``, with its name, material, shape, radius and trial count.
        grasps_per_object: grasps per object (default: 5-8 like the real data, or the
            table's ``Trials Recorded?``).
        seed: base seed (>= 0); everything is a deterministic function of it.
        image_size: stored image size (H, W) [px]; the field of view stays the real one.
        progress: show a progress bar.
        **options: ``dtype`` of the image/depth pickles (``float16`` default,
            ``float32``, ``float64``), ``workers`` (processes; default: all CPUs), and
            the fields of :class:`SimulationOptions` (``estimator_scale``,
            ``n_sessions``, ``curve_cell_mm``, ``render_cell_mm``, ``max_aug``, ``rig``: a
            ``GripperRig``, a name of ``rig.RIGS`` or a rig file's path).

    Returns:
        A :class:`GenerationReport` (counts, time, grasps/s).

    Raises:
        GenerationError: invalid arguments, or ``out_dir`` holds a dataset generated
            with different parameters.
    """
    from tactile_compliance.progress import progress_bar

    start = time.perf_counter()
    if n_objects is not None and object_table is not None:
        raise GenerationError("give either n_objects or object_table, not both")
    if seed < 0:
        raise GenerationError(f"seed must be >= 0, got {seed}")
    if grasps_per_object is not None and grasps_per_object < 1:
        raise GenerationError(f"grasps_per_object must be >= 1, got {grasps_per_object}")
    height, width = (int(v) for v in image_size)
    if height < 16 or width < 16:
        raise GenerationError(f"image_size must be at least 16 x 16 px, got {image_size}")
    sim_options, dtype, workers = _split_options(options)
    sim_options = replace(sim_options, image_size=(height, width))
    skipped_rows: list[str] = []
    if object_table is not None:
        specs, skipped_rows = objects_from_table(object_table, seed, grasps_per_object)
        source = f"table:{Path(object_table).name}"
    else:
        count = DEFAULT_N_OBJECTS if n_objects is None else int(n_objects)
        if count < 1:
            raise GenerationError(f"n_objects must be >= 1, got {count}")
        specs = default_objects(count, seed, grasps_per_object)
        source = "default-mix"

    out = claim_output_dir(out_dir, "simulate")
    manifest = {
        "format": FORMAT,
        "seed": seed,
        "source": source,
        "image_size": [height, width],
        # Through JSON, so tuples compare equal to the lists a resumed run reads back.
        "options": json.loads(
            json.dumps({k: v for k, v in asdict(sim_options).items() if k != "image_size"})
        ),
        "dtype": dtype,
        "grasps_per_object": grasps_per_object,
        # Importers copy it into the store: checkpoints and live estimates follow it.
        "analytical_estimator": DEFAULT_ESTIMATOR.name,
    }
    _check_manifest(out, manifest)
    manifest["objects"] = len(specs)
    with atomic_file(out / SYNTHETIC_MANIFEST) as handle:
        handle.write(json.dumps(manifest, indent=2, sort_keys=True) + "\n")
    # Leftovers of an interrupted run are incomplete by construction.
    for partial in out.glob(f"{PARTIAL_PREFIX}*"):
        shutil.rmtree(partial, ignore_errors=True)

    report = GenerationReport(out_dir=out, objects_total=len(specs), skipped_rows=skipped_rows)
    todo = [s for s in specs if not (out / s.name).is_dir()]
    report.objects_existing = len(specs) - len(todo)
    jobs = [_Job(s, seed, sim_options, dtype, out) for s in todo]
    n_workers = max(1, min(workers or os.cpu_count() or 1, len(jobs) or 1))
    report.workers = n_workers

    def account(result: tuple[int, int, int]) -> None:
        grasps, rejected, samples = result
        report.objects_written += 1
        report.grasps += grasps
        report.grasps_rejected += rejected
        report.samples += samples

    with progress_bar("simulating objects", len(jobs), enabled=progress) as advance:
        if n_workers == 1:
            for job in jobs:
                account(_run_object(job))
                advance(1)
        else:
            # Fork keeps start-up cheap; each object is independent of the others.
            with ProcessPoolExecutor(n_workers, mp_context=get_context("fork")) as pool:
                pending: set[Future[tuple[int, int, int]]] = set()
                queue = list(jobs)
                try:
                    while queue or pending:
                        while queue and len(pending) < 2 * n_workers:
                            pending.add(pool.submit(_run_object, queue.pop(0)))
                        done, pending = wait(pending, return_when=FIRST_COMPLETED)
                        for future in done:
                            account(future.result())
                            advance(1)
                except BaseException:
                    for future in pending:
                        future.cancel()
                    raise
    report.seconds = time.perf_counter() - start
    return report
