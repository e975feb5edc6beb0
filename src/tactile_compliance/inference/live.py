"""Live estimation (``tactile-compliance live``): a frame source plus force/width readings
through one streaming estimator per checkpoint. See docs/inference.md, "``live``".
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from tactile_compliance.acquisition.calibration import SensorCalibration
from tactile_compliance.acquisition.first_frame import check_recording, same_replay
from tactile_compliance.acquisition.readings import (
    ReadingError,
    ReadingsCallback,
    checked_reading,
    milliseconds_check,
)
from tactile_compliance.acquisition.recording import recording_estimator
from tactile_compliance.acquisition.sensors import (
    FrameError,
    FrameSizeError,
    FrameSourceBase,
    StampedOnArrival,
    iter_frames,
    read_on_arrival,
)
from tactile_compliance.data.depth_model import grey_frame_problem
from tactile_compliance.data.image_ops import difference_images
from tactile_compliance.data.inputs import ANALYTICAL_INPUTS, InputStrategy
from tactile_compliance.data.photometric import reconstruct_depth
from tactile_compliance.data.store import frames_to_uint8
from tactile_compliance.devices import DEFAULT_DEVICE
from tactile_compliance.inference.analytical import AnalyticalStream
from tactile_compliance.inference.base import BaseEstimator
from tactile_compliance.inference.ensemble import EnsembleEstimator
from tactile_compliance.inference.estimator import ComplianceEstimator
from tactile_compliance.inference.streaming import StreamEstimate, StreamingEstimator
from tactile_compliance.physics.estimators import WEDGE_UNITS

__all__ = ["format_live_event", "live_estimates", "load_members"]


def load_members(
    checkpoints: Sequence[str | Path],
    *,
    device: str = DEFAULT_DEVICE,
    backbone_weights: str | Path | None = None,
) -> list[ComplianceEstimator]:
    """Estimators of the given models: checkpoints (``best.pt`` or a run directory) or
    directories written by ``export --safetensors`` (holding ``model.safetensors``)."""
    if not checkpoints:
        raise ValueError("give at least one checkpoint")
    return [
        ComplianceEstimator.load(p, device=device, backbone_weights=backbone_weights)
        for p in checkpoints
    ]


def live_estimates(
    members: Sequence[BaseEstimator],
    source: FrameSourceBase | None,
    readings: ReadingsCallback,
    *,
    calibration: SensorCalibration | None = None,
    window: int | None = None,
    window_s: float | None = None,
    level: float = 0.8,
    scale: float = 1.0,
    readings_offset_s: float = 0.0,
    rig_stiffness_n_per_m: float | None = None,
) -> Iterator[dict[str, Any]]:
    """Run ``source`` through streaming estimators; yield one dict per event:
    ``estimate``, ``skipped``, ``warning`` or ``no_estimate`` (``{"event": KIND, ...}``).

    A background thread (``StampedOnArrival``) reads a live device, so each frame is
    stamped when it arrives, not when the estimator gets to it; replays are read in line.
    ``estimate`` events carry the ensemble's mean, interval and the frames used
    (``format_live_event``), provisional while the gripper closes and ``final`` on
    release; ``skipped`` names a frame that had no usable reading; ``warning`` a check of
    the recording (reference, force spikes); ``no_estimate`` ends a grasp that gave none,
    with its cause.

    Args:
        members: one estimator, or several for an ensemble interval; none: the
            analytical estimates alone (``inference.analytical.AnalyticalStream``, events
            with ``estimates_pa``, ``elastic_pa`` and ``hertz_pa``), no model.
        source: an open frame source (open it with the calibration's geometry); None: no
            camera, for frame-free members (``FW``, ``FWE``), which then run on the
            readings' own timestamps (``readings`` must be a recorded ``Readings``).
        readings: ``timestamp_s -> (force_n, width_m)``.
        calibration: the no-contact frame, depth model and pixel density (default: the
            first frame, the dataset heuristic at 16.40 px/mm).
        window, window_s: ``StreamingEstimator``'s window in frames or seconds.
        level, scale: the ensemble interval (``EnsembleEstimator``).
        readings_offset_s: the readings' clock minus the source's, in s.
        rig_stiffness_n_per_m: the rig's stiffness [N/m]; without members, each estimate
            event also carries ``rig_corrected_pa`` (``estimate --rig``'s pair). Members
            given: ValueError (a model has no rig-corrected estimate).
    """
    if not math.isfinite(readings_offset_s):
        raise ValueError(
            f"--readings-offset-s must be a finite number of s, got {readings_offset_s}"
        )
    if members and rig_stiffness_n_per_m is not None:
        raise ValueError(
            "--rig adds the rig-corrected analytical estimates to `live` without a model; "
            "a model gives its own estimate (leave out --rig or the checkpoints)"
        )
    if source is None:
        if not members:
            raise ValueError("the analytical estimates need frames: give a frame source")
        yield from _readings_only(members, readings, window, window_s, level, scale)
        return
    stamped = read_on_arrival(source)  # a live source: read by a thread, stamped on arrival
    reader = stamped if stamped is not source else None
    source = stamped
    try:
        ensemble = EnsembleEstimator(list(members), level=level, scale=scale) if members else None
        reference = None if calibration is None else calibration.reference
        depth_model = "dataset" if calibration is None else calibration.depth
        # Each frame is differenced once, here: the depth map and every member's stream
        # (``frame_kind="difference"``) take the same difference image.
        streams = [
            StreamingEstimator(
                member,
                window=window,
                window_s=window_s,
                frame_kind="difference",
                channel_order="BGR",
            )
            for member in members
        ] or [
            AnalyticalStream(
                recording_estimator(calibration),
                rig_stiffness_n_per_m=rig_stiffness_n_per_m,
                window=window,
                window_s=window_s,
                frame_kind="difference",
                channel_order="BGR",
            )
        ]
        # Depth maps feed the analytical estimates and the depth-map models; both are in the
        # units of the depth model and pixel density they were made with.
        needs_depth = ensemble is None or bool(
            {*ANALYTICAL_INPUTS, "depth"} & set(ensemble.required_inputs)
        )
        units = WEDGE_UNITS if calibration is None else calibration.units
        for member in members:
            member.run_inputs.check_sensor(
                units, trained=f"checkpoint {member.source}", used="this sensor"
            )

        skipped: list[FrameError] = []
        reported: set[int] = set()  # force spikes reported (a followed log finds them late)
        first = True
        kind = "first frame" if reference is None else "calibration"
        skips: list[str] = []  # every skip's reason, for the cause of a missing estimate
        units_decided = False
        for timestamp_s, frame in iter_frames(source, skipped.append):
            while skipped:
                skips.append(str(skipped.pop(0)))
                yield {"event": "skipped", "reason": skips[-1]}
            if not units_decided:  # milliseconds for seconds: no frame would find its reading
                problem, units_decided = milliseconds_check(
                    readings, timestamp_s + readings_offset_s
                )
                if problem:
                    raise ValueError(problem)
            try:
                force_n, width_m = checked_reading(readings, timestamp_s + readings_offset_s)
            except ReadingError as err:
                skips.append(f"frame at {timestamp_s:.4f} s: {err}")
                yield {"event": "skipped", "reason": skips[-1]}
                continue
            if reference is None:
                reference = frame  # right if the grasp starts without contact (checked below)
            if first:
                first = False
                # Once: a source yields frames of one shape (acquisition.sensors), and each
                # stream holds every later frame to the first one's.
                if reference.shape != frame.shape:
                    raise FrameSizeError(
                        f"the reference frame is {reference.shape}, the source's frames "
                        f"{frame.shape}"
                    )
                if calibration is not None and calibration.depth_model is not None:
                    problem = grey_frame_problem(frame, reference)
                    if problem:
                        raise ValueError(f"{source.name}: {problem}")
                warnings, checks = check_recording(
                    readings,
                    np.array([timestamp_s]),
                    np.array([force_n]),
                    frame,
                    reference,
                    kind,
                    reference_from_start=kind == "calibration" and same_replay(calibration, source),
                    remedy="a --calibration recorded before the grasp",
                )
                reported.update(s["index"] for s in checks["spikes"])
                for warning in warnings:
                    yield {"event": "warning", "reason": warning}
                # Once per run, not per member: members of an ensemble share their data.
                mismatches = dict.fromkeys(
                    line
                    for member in members
                    for line in member.run_inputs.source_mismatch(
                        frame.shape[:2], units, used=source.name
                    )
                )
                for line in mismatches:
                    yield {"event": "warning", "reason": line}
            for spike in getattr(readings, "spikes", None) or ():
                if spike.index not in reported:
                    reported.add(spike.index)
                    yield {"event": "warning", "reason": spike.describe()}
            diff = difference_images(frame[None], reference)
            depth = reconstruct_depth(diff, model=depth_model)[0] if needs_depth else None
            # Quantised like the store (and like StreamingEstimator's raw frames), so the
            # models see the training frames' encoding.
            model_frame = frames_to_uint8(diff[0])
            # Frames waiting: skip provisional estimates (never frames) to catch up.
            provisional = not (isinstance(source, StampedOnArrival) and source.pending)
            emitted = [
                stream.update(
                    model_frame,
                    force_n,
                    width_m,
                    depth_mm=depth,
                    timestamp_s=timestamp_s,
                    provisional=provisional,
                )
                for stream in streams
            ]
            if any(e is not None for e in emitted):
                event = _combine(ensemble, streams, timestamp_s)
                if event is not None:
                    yield event
                    if event["final"]:
                        return
            if all(stream.state == "done" for stream in streams):
                break  # released without a final estimate: say why below
        while skipped:
            skips.append(str(skipped.pop(0)))
            yield {"event": "skipped", "reason": skips[-1]}
        last = _finish(ensemble, streams)
        if last is not None:
            yield last
            return
        reason = _no_estimate_reason(streams[0], skips, needs_depth, analytical=ensemble is None)
        yield {"event": "no_estimate", "reason": reason}
    finally:
        if reader is not None:
            reader.stop()  # the caller owns the inner source and closes it


def _readings_only(
    members: Sequence[BaseEstimator],
    readings: ReadingsCallback,
    window: int | None,
    window_s: float | None,
    level: float,
    scale: float,
) -> Iterator[dict[str, Any]]:
    """``live_estimates`` without a camera: frame-free members fed the recorded readings
    at their own timestamps (the events are the same)."""
    for member in members:
        if member.inputs.image is not None:
            raise ValueError(
                f"checkpoint {member.source} (inputs={member.inputs.value}) reads "
                f"{member.inputs.image.name}, but the source `none` gives no camera: name a "
                f"sensor or video, or use a frame-free checkpoint (FW, FWE)"
            )
        if ANALYTICAL_INPUTS & set(member.inputs.input_names):
            raise ValueError(
                f"checkpoint {member.source} (inputs={member.inputs.value}) takes "
                f"analytical estimates, which come from the frames' depth maps; the source "
                f"`none` gives no camera: name a sensor or video (the model reads no frames "
                f"itself), or use an FW checkpoint"
            )
    times = getattr(readings, "timestamp_s", None)
    if times is None:
        raise ValueError("the source `none` needs recorded readings (a CSV), not a live log")
    ensemble = EnsembleEstimator(list(members), level=level, scale=scale)
    streams = [StreamingEstimator(m, window=window, window_s=window_s) for m in members]
    for timestamp_s in np.asarray(times, dtype=np.float64):
        force_n, width_m = checked_reading(readings, float(timestamp_s))
        emitted = [
            stream.update(None, force_n, width_m, timestamp_s=float(timestamp_s))
            for stream in streams
        ]
        if any(e is not None for e in emitted):
            event = _combine(ensemble, streams, float(timestamp_s))
            if event is not None:
                yield event
                if event["final"]:
                    return
        if all(stream.state == "done" for stream in streams):
            break
    last = _finish(ensemble, streams)
    if last is not None:
        yield last
        return
    yield {"event": "no_estimate", "reason": _no_estimate_reason(streams[0], [], False)}


def _finish(
    ensemble: EnsembleEstimator | None, streams: list[StreamingEstimator]
) -> dict[str, Any] | None:
    """The final event when the source ends before a release: every stream finished, and
    their final estimates combined (None when no stream has one)."""
    finals = [stream.finish() for stream in streams]
    if any(f is not None for f in finals):
        return _combine(ensemble, streams, None)
    return None


def _no_estimate_reason(
    stream: StreamingEstimator, skips: list[str], needs_depth: bool, analytical: bool = False
) -> str:
    """Why a stream ended without an estimate, the real cause first."""
    if stream.frames_seen == 0:
        reason = f"every frame was skipped ({len(skips)})"
        if skips:
            reason += f"; first: {skips[0]}"
        if any("reading" in s for s in skips):
            reason += " (are the readings on the frames' clock? see --readings-offset-s)"
        return reason
    if not stream.has_selection:
        return (
            f"the grasp never reached the frame selection (a frame >= 5 N, a peak >= 10 N, "
            f"three frames from contact to peak): peak force {stream.peak_force_n:.1f} N "
            f"over {stream.frames_seen} frames"
        )
    if analytical:
        return (
            "the frames were selected, but the analytical estimates could not be computed "
            "from the depth maps: too little contact area or depth at this frame size and "
            "pixel density (calibrate the sensor's px/mm, docs/sensors.md)"
        )
    if needs_depth:
        takers = ", ".join(s.value for s in InputStrategy if ANALYTICAL_INPUTS & set(s.input_names))
        return (
            f"the frames were selected, but the analytical estimates ({takers} inputs) "
            "could not be computed from the depth maps: too little contact area or depth at "
            "this frame size and pixel density (calibrate the sensor's px/mm, docs/sensors.md), "
            "or use an Image, ImageF or ImageFW checkpoint"
        )
    return f"the stream ended without a final estimate after {stream.frames_seen} frames"


def _combine(
    ensemble: EnsembleEstimator | None, streams: list[StreamingEstimator], timestamp_s: float | None
) -> dict[str, Any] | None:
    """One event from the members' latest estimates (None until every member has one)."""
    latest = [s.latest for s in streams]
    if any(e is None for e in latest):
        return None
    estimates: list[StreamEstimate] = latest  # type: ignore[assignment]
    event = {"event": "estimate", "timestamp_s": timestamp_s, **estimates[0].to_dict()}
    event["final"] = all(e.final for e in estimates)
    if ensemble is not None and len(estimates) > 1:
        combined = ensemble.combine(np.array([e.log10_modulus_pa for e in estimates]))
        event.update(
            modulus_pa=float(combined.modulus_pa),
            log10_modulus_pa=float(combined.log10_modulus_pa),
            std_decades=float(combined.std_decades),
            interval_pa=[float(v) for v in combined.interval_pa],
            level=combined.level,
            members_log10=[float(v) for v in combined.members_log10],
        )
    return event


def format_live_event(event: dict[str, Any]) -> str:
    """One human-readable line per event (what ``live`` prints without ``--json``)."""
    if event["event"] != "estimate":  # skipped, warning
        return f"{event['event']:<11} {event['reason']}"
    kind = "final      " if event["final"] else "provisional"
    when = "" if event["timestamp_s"] is None else f" t={event['timestamp_s']:.3f} s"
    if "estimates_pa" in event:  # no model: the analytical estimates
        line = (
            f"{kind} elastic E = {event['elastic_pa']:.4g} Pa, Hertz E* = "
            f"{event['hertz_pa']:.4g} Pa  frames {tuple(event['frame_indices'])} of "
            f"{event['frames_seen']}{when}"
        )
        if event.get("rig_corrected_pa") is not None:
            elastic, hertz = (
                "-" if v is None else f"{v:.4g} Pa" for v in event["rig_corrected_pa"]
            )
            line += f"  rig-corrected elastic E = {elastic}, Hertz E* = {hertz}"
        return line
    line = (
        f"{kind} E = {event['modulus_pa']:.4g} Pa (log10 {event['log10_modulus_pa']:.3f})"
        f"  frames {tuple(event['frame_indices'])} of {event['frames_seen']}{when}"
    )
    if "interval_pa" in event:
        low, high = event["interval_pa"]
        line += f"  {event['level']:.0%} interval {low:.3g}..{high:.3g} Pa"
    return line
