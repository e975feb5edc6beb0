"""Streaming estimation: frames with force/width readings one at a time, estimates as
soon as the dataset's frame rule allows. See docs/inference.md, "Streaming from a live
sensor".
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from tactile_compliance.data.frame_selection import (
    MIN_PEAK_FORCE_N,
    ONSET_FORCE_N,
    PEAK_FRACTION,
    FrameSelection,
    check_window,
    check_window_s,
    select_frame_indices,
)
from tactile_compliance.data.image_ops import difference_images
from tactile_compliance.data.inputs import ANALYTICAL_INPUTS, INPUTS
from tactile_compliance.data.store import frames_to_uint8, store_depth_maps
from tactile_compliance.inference.input_checks import check_frames
from tactile_compliance.models import NUM_FRAMES
from tactile_compliance.physics.estimators import AnalyticalEstimator

if TYPE_CHECKING:
    from tactile_compliance.inference.base import BaseEstimator, Prediction

__all__ = [
    "StreamEstimate",
    "StreamingEstimator",
    "difference_image",
    "predict_trajectory",
]

FrameKind = Literal["difference", "raw"]


def _check_frame_kind(frame_kind: str) -> FrameKind:
    if frame_kind not in ("difference", "raw"):
        raise ValueError(f"frame_kind must be 'difference' or 'raw', got {frame_kind!r}")
    return frame_kind  # type: ignore[return-value]


def _as_difference_images(
    frames: np.ndarray, frame_kind: str, reference: np.ndarray | None
) -> np.ndarray:
    """Selected frames (3, H, W, 3) as the model takes them: raw frames are differenced
    (already checked by ``StreamingEstimator._check_frame``, so not checked again)."""
    if _check_frame_kind(frame_kind) == "difference":
        return frames
    assert reference is not None  # a raw stream keeps its first frame as the reference
    return frames_to_uint8(difference_images(frames, reference))


def _camera_frame(value: Any) -> np.ndarray:
    """The shape rule of a raw camera frame: one (H, W, 3) uint8 image."""
    array = np.asarray(value)
    if array.ndim != 3 or array.shape[-1] != 3 or array.dtype != np.uint8:
        raise ValueError(
            f"raw frames must be uint8 camera images (H, W, 3), got {array.dtype} "
            f"{tuple(array.shape)}"
        )
    return array


def difference_image(frame: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Raw uint8 camera frame (H, W, 3) -> difference image against the no-contact
    ``reference`` (``data.image_ops.difference_images``), quantised like the importer
    stores frames (``frames_to_uint8``), so the model sees the training frames' encoding.

    Raises:
        ValueError: either is not a uint8 (H, W, 3) image, or their shapes differ.
    """
    frame, reference = _camera_frame(frame), _camera_frame(reference)
    if frame.shape != reference.shape:
        raise ValueError(f"raw frame {frame.shape} and reference {reference.shape} differ")
    return frames_to_uint8(difference_images(frame[None], reference)[0])


@dataclass(frozen=True)
class StreamEstimate:
    """One estimate emitted by a stream.

    Attributes:
        modulus_pa: Young's modulus E in Pa.
        log10_modulus_pa: log10 E.
        frame_indices: the three frames used (indices since the stream started or was reset).
        onset_frame: contact onset (first frame with F >= the onset force).
        peak_frame: first frame with F >= peak_fraction x F_max so far.
        frames_seen: frames received when the estimate was made.
        final: True for the last estimate of the grasp (released or ``finish()``).
        force_n: force at the three frames (N).
        width_m: width at the three frames (m), None if not streamed.
        window: the window length in frames, None for the whole trajectory.
        frame_times_s: timestamps (s) of the three frames, None without timestamps.
        window_s: the window length in s (``window_s=``), else None.
    """

    modulus_pa: float
    log10_modulus_pa: float
    frame_indices: tuple[int, int, int]
    onset_frame: int
    peak_frame: int
    frames_seen: int
    final: bool
    force_n: tuple[float, float, float]
    width_m: tuple[float, float, float] | None
    window: int | None
    frame_times_s: tuple[float, float, float] | None = None
    window_s: float | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly dict (lists for tuples)."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}


def _check_reading(name: str, value: Any, unit: str) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{name} must be a number in {unit}, got {value!r}") from err
    if not np.isfinite(number):
        raise ValueError(f"{name} must be finite ({unit}), got {number}")
    return number


@dataclass
class _Buffer:
    """Frames and readings since the stream started; old frames are dropped by offset."""

    offset: int = 0  # global index of frames[0]
    frames: list[np.ndarray | None] = field(default_factory=list)  # None: frame-free model
    depths: list[np.ndarray | None] = field(default_factory=list)
    forces: list[float] = field(default_factory=list)  # every frame (cheap), global index
    widths: list[float] = field(default_factory=list)
    times: list[float] = field(default_factory=list)  # s, every frame, when timestamped


class StreamingEstimator:
    """Feed frames + force/width one at a time; get an estimate as soon as possible.

    Every update needs the normal force (N): frames are selected by force, whatever the
    strategy. The final estimate (on release or :meth:`finish`) equals
    :func:`predict_trajectory` on the same frames.

    Args:
        estimator: any :class:`~tactile_compliance.inference.base.BaseEstimator`.
        window: None (whole trajectory, the dataset's rule) or n >= 3 (last n frames).
        window_s: the same in time: the last ``window_s`` seconds up to the peak (needs
            ``timestamp_s`` with every update); exclusive with ``window``.
        frame_kind: ``"difference"`` (difference images, uint8 or float [0, 1]) or
            ``"raw"`` (uint8 camera frames, differenced against ``reference``).
        reference: raw no-contact frame for ``frame_kind="raw"``; default the first frame.
        channel_order: ``"RGB"`` or ``"BGR"`` (OpenCV cameras) of the frames.
        analytical_estimator: the estimator computing E from ``depth_mm``; default the
            checkpoint's (``RunInputs.estimator``, at its sensor's pixel density, over its
            ``window_start``), so live values follow the training data's distribution.
        onset_force_n, peak_fraction, min_peak_force_n: the selection rule (dataset values).
        release_fraction: the grasp ends (final estimate) when, after reaching the minimum
            peak force, the force falls below this fraction of F_max.
        max_frames: buffer bound; a grasp still running after this many frames since
            onset is finalised (whole-trajectory mode keeps every frame since onset).
    """

    def __init__(
        self,
        estimator: BaseEstimator,
        *,
        window: int | None = None,
        window_s: float | None = None,
        frame_kind: FrameKind = "difference",
        reference: np.ndarray | None = None,
        channel_order: str = "RGB",
        estimates_pa: Any = None,
        analytical_estimator: AnalyticalEstimator | None = None,
        onset_force_n: float = ONSET_FORCE_N,
        peak_fraction: float = PEAK_FRACTION,
        min_peak_force_n: float = MIN_PEAK_FORCE_N,
        release_fraction: float = 0.5,
        max_frames: int = 900,
    ) -> None:
        self.window = check_window(window)
        self.window_s = check_window_s(window_s)
        if self.window is not None and self.window_s is not None:
            raise ValueError("give window (frames) or window_s (seconds), not both")
        self.frame_kind = _check_frame_kind(frame_kind)
        if not 0 < peak_fraction <= 1:
            raise ValueError(f"peak_fraction must be in (0, 1], got {peak_fraction}")
        if not 0 <= release_fraction < peak_fraction:
            raise ValueError(
                f"release_fraction must be in [0, peak_fraction), got {release_fraction}"
            )
        if onset_force_n <= 0 or min_peak_force_n < onset_force_n:
            raise ValueError("need 0 < onset_force_n <= min_peak_force_n (N)")
        if max_frames < NUM_FRAMES:
            raise ValueError(f"max_frames must be >= {NUM_FRAMES}, got {max_frames}")
        self.estimator = estimator
        #: The estimator computing E from depth maps (``physics.estimators``).
        self.analytical_estimator = analytical_estimator or estimator.run_inputs.estimator
        self.channel_order = channel_order
        self.onset_force_n = float(onset_force_n)
        self.peak_fraction = float(peak_fraction)
        self.min_peak_force_n = float(min_peak_force_n)
        self.release_fraction = float(release_fraction)
        self.max_frames = int(max_frames)
        self._initial_reference = None if reference is None else _camera_frame(reference)
        self._initial_estimates = (
            None if estimates_pa is None else self._check_estimates(estimates_pa)
        )
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget the current grasp (keeps the options and an explicit reference frame)."""
        self._buffer = _Buffer()
        self._reference = self._initial_reference
        self._estimates_pa = self._initial_estimates
        self._frame_shape: tuple[int, ...] | None = None  # the grasp's first frame's
        self._frame_dtype: np.dtype | None = None
        self._last: StreamEstimate | None = None
        self._last_key: tuple[Any, ...] | None = None
        self._done = False
        self._has_depth: bool | None = None
        self._has_times: bool | None = None

    @property
    def state(self) -> str:
        """``"waiting"`` (no contact yet), ``"pressing"`` or ``"done"`` (final emitted)."""
        if self._done:
            return "done"
        forces = self._buffer.forces
        return "pressing" if any(f >= self.onset_force_n for f in forces) else "waiting"

    @property
    def latest(self) -> StreamEstimate | None:
        """The most recent estimate (None before the first one)."""
        return self._last

    @property
    def frames_seen(self) -> int:
        """Frames received since the stream started or was reset."""
        return len(self._buffer.forces)

    # ------------------------------------------------------------------ input checks
    def _check_frame(self, frame: Any) -> np.ndarray:
        """The frame as an array. The first frame of a grasp is checked whole, by the
        rule ``predict`` applies (``input_checks.check_frames``: shape, dtype, range,
        minimum size) or, raw, as a camera frame the size of the reference; later frames
        only have to keep its shape and dtype (and floats be finite), so each frame's
        shape is checked once on its way to the model."""
        array = np.asarray(frame)
        if self._frame_shape is not None:
            if array.shape != self._frame_shape or array.dtype != self._frame_dtype:
                raise ValueError(
                    f"frame shape changed from {self._frame_dtype} {self._frame_shape} to "
                    f"{array.dtype} {array.shape} within a grasp"
                )
            if array.dtype.kind == "f" and not np.all(np.isfinite(array)):
                raise ValueError("frame contains NaN/inf values")
        elif self.frame_kind == "raw":
            _camera_frame(array)
            if self._reference is not None and array.shape != self._reference.shape:
                raise ValueError(
                    f"raw frame {array.shape} and reference {self._reference.shape} differ"
                )
        else:
            if array.ndim != 3 or array.shape[-1] != 3:  # one frame; predict takes three
                raise ValueError(
                    f"a streamed frame must be one difference image (H, W, 3), got "
                    f"{array.dtype} {tuple(array.shape)}"
                )
            check_frames(
                np.broadcast_to(array, (NUM_FRAMES, *array.shape)),
                channel_order=self.channel_order,
            )  # NaN/inf included
        return array

    @staticmethod
    def _check_estimates(value: Any) -> np.ndarray:
        array = np.asarray(value, dtype=np.float64).reshape(-1)
        if array.shape != (2,) or not np.all(np.isfinite(array)):
            raise ValueError(
                f"estimates_pa must be two finite values (elastic E, Hertz E*) in Pa, got {value!r}"
            )
        return array

    # ------------------------------------------------------------------ feeding
    def update(
        self,
        frame: Any,
        force_n: float,
        width_m: float | None = None,
        *,
        estimates_pa: Any = None,
        depth_mm: Any = None,
        timestamp_s: float | None = None,
        provisional: bool = True,
    ) -> StreamEstimate | None:
        """Add one frame and its readings; returns a new estimate (a refinement or the
        final one) or None. After the final estimate, frames are ignored until :meth:`reset`.

        Args:
            frame: (H, W, 3) difference image or raw frame (see ``frame_kind``); None for
                a model without frames (``FW``, ``FWE``: no camera needed), ignored by one.
            estimates_pa: (elastic E, Hertz E*) in Pa, replaces earlier values.
            depth_mm: (H', W') gel depth map in mm of this frame (give it with every frame
                or never): the estimates are computed from it on the fly (the
                rig-corrected pair of an ``FWR`` model at the checkpoint's
                ``RunInputs.rig_stiffness_n_per_m``; it cannot be given), and a depth-map
                model (``DepthFW``, ``DepthALL``) reads it, resized as the store keeps
                depth maps (``data.store.store_depth_maps``).
            timestamp_s: capture time in s on a clock that only moves forward; with every
                frame or never.
            provisional: False adds the frame without a provisional estimate (a consumer
                that is behind its sensor catches up); the final estimate is the same.

        Raises:
            ValueError: a bad frame, reading or timestamp; the frame is not added, the
                stream goes on.
        """
        if self._done:
            return None
        uses = self.estimator.required_inputs
        if "frames" in uses and frame is None:
            raise ValueError(
                f"this checkpoint uses inputs={self.estimator.inputs.value}: every update "
                f"needs a frame"
            )
        array = self._check_frame(frame) if "frames" in uses else None
        if "depth" in uses and depth_mm is None:
            raise ValueError(
                f"this checkpoint uses inputs={self.estimator.inputs.value}: every update "
                f"needs depth_mm (the frame's depth map in mm)"
            )
        force = _check_reading("force_n", force_n, "N")
        if width_m is None and "width" in self.estimator.required_inputs:
            raise ValueError(
                f"this checkpoint uses inputs={self.estimator.inputs.value}: every "
                f"update needs width_m (gripper width in m)"
            )
        width = float("nan") if width_m is None else _check_reading("width_m", width_m, "m")
        time_s = self._check_timestamp(timestamp_s)
        if estimates_pa is not None:
            self._estimates_pa = self._check_estimates(estimates_pa)
        has_depth = depth_mm is not None
        if self._has_depth is None:
            self._has_depth = has_depth
        elif has_depth != self._has_depth:
            raise ValueError("depth_mm must be given with every frame of a grasp or never")
        if array is not None and self.frame_kind == "raw" and self._reference is None:
            # The first frame of a grasp recording shows the gel without contact.
            self._reference = array.copy()

        buf = self._buffer
        self._has_times = time_s is not None
        if time_s is not None:
            buf.times.append(time_s)
        buf.forces.append(force)
        buf.widths.append(width)
        buf.frames.append(None if array is None else array.copy())
        if array is not None and self._frame_shape is None:  # set once the frame is added
            self._frame_shape, self._frame_dtype = array.shape, array.dtype
        buf.depths.append(np.asarray(depth_mm, dtype=np.float64) if has_depth else None)
        self._trim()

        forces = np.asarray(buf.forces)
        f_max = float(forces.max())
        # Reaching the minimum peak force implies contact, so this is a release after a press.
        released = f_max >= self.min_peak_force_n and force < self.release_fraction * f_max
        onset = np.flatnonzero(forces >= self.onset_force_n)
        overflow = onset.size > 0 and len(forces) - int(onset[0]) >= self.max_frames
        if released or overflow:
            return self.finish()
        return self._estimate(final=False) if provisional else None

    def _check_timestamp(self, timestamp_s: Any) -> float | None:
        """The frame's time in s, checked against the stream's (nothing is changed)."""
        has_time = timestamp_s is not None
        if self._has_times is not None and has_time != self._has_times:
            raise ValueError(
                "timestamp_s must be given with every frame of a grasp or never "
                f"({'missing' if self._has_times else 'given'} for frame {self.frames_seen}; "
                "the frame was not added)"
            )
        if not has_time:
            if self.window_s is not None:
                raise ValueError(
                    "window_s (a window in seconds) needs timestamp_s with every frame"
                )
            return None
        time_s = _check_reading("timestamp_s", timestamp_s, "s")
        times = self._buffer.times
        if times and time_s <= times[-1]:
            raise ValueError(
                f"timestamp_s went backwards or repeated: {time_s:.6f} s after "
                f"{times[-1]:.6f} s; the frame was not added, the {len(times)} frames "
                f"received so far are kept"
            )
        return time_s

    def _trim(self) -> None:
        """Drop frames that no future selection can use (bounded memory)."""
        buf = self._buffer
        forces = np.asarray(buf.forces)
        onset = np.flatnonzero(forces >= self.onset_force_n)
        # The dataset's estimator fits from one frame before F first reaches 2.5 N.
        press = self._press_start(forces)
        if onset.size == 0:
            # Before contact only the newest frame matters (and, for the dataset's
            # estimator, the press so far, bounded by max_frames).
            keep_from = (
                len(forces) - 1 if press is None else max(press, len(forces) - self.max_frames)
            )
        elif self.window is None and self.window_s is None:
            keep_from = int(onset[0]) if press is None else min(int(onset[0]), press)
        else:
            # i_peak never moves backwards (F_max only grows), so frames before the
            # current window start are never selected again.
            selection = self._select(any_peak=True)
            keep_from = selection.window_start if selection is not None else int(onset[0])
        drop = keep_from - buf.offset
        if drop > 0:
            del buf.frames[:drop]
            del buf.depths[:drop]
            buf.offset += drop

    def _press_start(self, forces: np.ndarray) -> int | None:
        """First frame the estimator's series starts at when it computes the estimates
        from depth maps (``AnalyticalEstimator.window_start``); else None."""
        if not self._has_depth:
            return None
        return self.analytical_estimator.window_start(forces)

    @property
    def has_selection(self) -> bool:
        """Whether the frames so far meet the selection rule (three frames chosen)."""
        return bool(self._buffer.forces) and self._select() is not None

    @property
    def peak_force_n(self) -> float:
        """The highest force [N] of the grasp so far (NaN before the first frame)."""
        return float(max(self._buffer.forces)) if self._buffer.forces else float("nan")

    def finish(self) -> StreamEstimate | None:
        """End the grasp now: the final estimate (None if the grasp never had enough data)."""
        if self._done:
            return self._last if self._last is not None and self._last.final else None
        estimate = self._estimate(final=True)
        self._done = True
        return estimate

    # ------------------------------------------------------------------ estimation
    def _select(self, *, any_peak: bool = False) -> FrameSelection | None:
        """The selection on the frames so far; ``any_peak`` waives the minimum peak force."""
        return select_frame_indices(
            self._buffer.forces,
            window=self.window,
            timestamps_s=self._buffer.times if self._has_times else None,
            window_s=self.window_s,
            onset_force_n=self.onset_force_n,
            peak_fraction=self.peak_fraction,
            min_peak_force_n=0.0 if any_peak else self.min_peak_force_n,
        )

    def _current_estimates(
        self, name: str, selection: FrameSelection, final: bool
    ) -> np.ndarray | None:
        """The analytical input ``name`` (``"estimates"`` or ``"rig_estimates"``, Pa) of
        the frames so far: given ones (``estimates_pa``), else computed from the depth
        maps (the rig-corrected pair at the checkpoint's rig stiffness); None when not
        given and not (yet) computable, unless the model takes missing estimates
        (``RunInputs.missing_estimates``): it then gets the pair with its NaN."""
        if name == "estimates" and self._estimates_pa is not None:
            return self._estimates_pa
        if not self._has_depth:
            return None
        rig_stiffness = None
        if name == "rig_estimates":
            rig_stiffness = self.estimator.run_inputs.rig_stiffness_n_per_m
        forces, widths, depths = self._estimation_series(selection, final)
        values = np.asarray(
            self.analytical_estimator.estimate(
                forces, widths, depths, rig_stiffness_n_per_m=rig_stiffness
            ),
            dtype=np.float64,
        )
        if np.all(np.isfinite(values)) or self._takes_missing_estimates():
            return values
        return None

    def _takes_missing_estimates(self) -> bool:
        """Whether the model estimates with NaN analytical inputs (``RunInputs.
        missing_estimates``); else the stream waits until they can be computed."""
        return self.estimator.run_inputs.missing_estimates

    def _estimation_series(
        self, selection: FrameSelection, final: bool
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The forces [N], widths [m] and depth maps [mm] the analytical estimator gets."""
        buf = self._buffer
        lo, hi = max(selection.window_start, buf.offset), selection.peak + 1
        press = self._press_start(np.asarray(buf.forces))
        if press is not None:
            # The dataset's estimator clips the whole recording itself (press by force,
            # depth onset, the end of the press after the peak): the final estimate gives
            # it everything since the press began, as the dataset's driver loaded it;
            # refinements stop at the peak so they change only when the peak does.
            lo, hi = max(press, buf.offset), (len(buf.forces) if final else hi)
        depths = np.stack(buf.depths[lo - buf.offset : hi - buf.offset])  # type: ignore[arg-type]
        return np.asarray(buf.forces)[lo:hi], np.asarray(buf.widths)[lo:hi], depths

    def _estimate(self, *, final: bool) -> StreamEstimate | None:
        selection = self._select()
        if selection is None:
            return None
        analytical: dict[str, np.ndarray] = {}
        for name in (n for n in self.estimator.required_inputs if n in ANALYTICAL_INPUTS):
            values = self._current_estimates(name, selection, final)
            if values is None:
                if self._has_depth:
                    return None  # not estimable yet from the depth maps; wait for more frames
                given = "" if name == "rig_estimates" else "give estimates_pa= in Pa, or "
                raise ValueError(
                    f"this checkpoint uses inputs={self.estimator.inputs.value}, which takes "
                    f"the {INPUTS[name].meaning}: {given}give depth_mm= with every frame"
                )
            analytical[name] = values
        # Bytes, not floats: a missing (NaN) estimate must equal itself here.
        key = (selection.indices, tuple((n, v.tobytes()) for n, v in analytical.items()))
        if key == self._last_key and self._last is not None:
            if not final:
                return None
            # Same frames as the last refinement: the final estimate is that one.
            estimate = replace(self._last, final=True, frames_seen=self.frames_seen)
        else:
            estimate = self._predict(selection, analytical, final)
        self._last, self._last_key = estimate, key
        return estimate

    def _predict(
        self, selection: FrameSelection, analytical: dict[str, np.ndarray], final: bool
    ) -> StreamEstimate:
        idx, buf = selection.indices, self._buffer
        forces = tuple(float(buf.forces[i]) for i in idx)
        widths_all = np.asarray(buf.widths)[list(idx)]
        widths = None if np.isnan(widths_all).any() else tuple(float(w) for w in widths_all)
        uses = self.estimator.required_inputs
        images: dict[str, Any] = {}
        if "frames" in uses:
            frames = np.stack([buf.frames[i - buf.offset] for i in idx])  # type: ignore[misc]
            images["frames"] = _as_difference_images(frames, self.frame_kind, self._reference)
        if "depth" in uses:
            depths = np.stack([buf.depths[i - buf.offset] for i in idx])  # type: ignore[misc]
            size = self.estimator.run_inputs.store_image_size
            images["depth"] = store_depth_maps(depths, size)
        prediction: Prediction = self.estimator.predict(
            force=np.asarray(forces),
            width=None if widths is None else np.asarray(widths),
            channel_order=self.channel_order,
            **analytical,
            **images,
        )
        return StreamEstimate(
            modulus_pa=float(prediction.modulus_pa),
            log10_modulus_pa=float(prediction.log10_modulus_pa),
            frame_indices=idx,
            onset_frame=selection.onset,
            peak_frame=selection.peak,
            frames_seen=self.frames_seen,
            final=final,
            force_n=forces,  # type: ignore[arg-type]
            width_m=widths,  # type: ignore[arg-type]
            window=self.window,
            frame_times_s=selection.times_s,
            window_s=self.window_s,
        )


def predict_trajectory(
    estimator: BaseEstimator,
    frames: Any,
    force_n: Any,
    width_m: Any = None,
    estimates_pa: Any = None,
    *,
    window: int | None = None,
    timestamps_s: Any = None,
    window_s: float | None = None,
    frame_kind: FrameKind = "difference",
    reference: np.ndarray | None = None,
    channel_order: str = "RGB",
    onset_force_n: float = ONSET_FORCE_N,
    peak_fraction: float = PEAK_FRACTION,
    min_peak_force_n: float = MIN_PEAK_FORCE_N,
) -> tuple[Prediction, FrameSelection]:
    """Batch estimate of a whole recorded grasp: select three frames by force, predict.

    Args:
        frames: (T, H, W, 3) difference images (or raw frames with ``frame_kind="raw"``).
        force_n, width_m: (T,) normal force in N, gripper width in m (when the model uses
            width).
        estimates_pa: (elastic E, Hertz E*) in Pa (ALL models).
        timestamps_s: (T,) capture times in s (increasing): select the frames in time;
            None keeps the index rule.
        window, window_s: as :class:`StreamingEstimator`'s.

    Returns:
        (prediction for the grasp, the frame selection used).

    Raises:
        ValueError: inconsistent lengths, or the grasp never reaches the selection
            thresholds (no contact, peak below ``min_peak_force_n``, too few frames).
    """
    frames = np.asarray(frames)
    forces = np.asarray(force_n, dtype=np.float64).reshape(-1)
    if frames.ndim != 4 or frames.shape[-1] != 3:
        raise ValueError(f"frames must be a (T, H, W, 3) sequence, got {tuple(frames.shape)}")
    if len(frames) != len(forces):
        raise ValueError(f"{len(frames)} frames but {len(forces)} force readings")
    widths = None
    if width_m is not None:
        widths = np.asarray(width_m, dtype=np.float64).reshape(-1)
        if len(widths) != len(forces):
            raise ValueError(f"{len(frames)} frames but {len(widths)} width readings")
    selection = select_frame_indices(
        forces,
        window=window,
        timestamps_s=timestamps_s,
        window_s=window_s,
        onset_force_n=onset_force_n,
        peak_fraction=peak_fraction,
        min_peak_force_n=min_peak_force_n,
    )
    if selection is None:
        raise ValueError(
            f"no frame selection possible: the force never reaches {onset_force_n:g} N, "
            f"peaks below {min_peak_force_n:g} N, or rises in fewer than "
            f"{NUM_FRAMES} frames"
        )
    idx = list(selection.indices)
    # A recording's first frame shows the gel without contact: the default reference.
    ref = frames[0] if reference is None else np.asarray(reference)
    chosen = _as_difference_images(frames[idx], frame_kind, ref)
    prediction = estimator.predict(
        chosen,
        force=forces[idx],
        width=None if widths is None else widths[idx],
        estimates=estimates_pa,
        channel_order=channel_order,
    )
    return prediction, selection
