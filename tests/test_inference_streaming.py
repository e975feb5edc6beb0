"""Streaming estimation (frame selection by force, window, raw frames) and ensembles.

The expected frame indices are computed here from the rule in DATA_FORMATS.md, not with
the module under test, so a wrong selection or a buffering bug fails the comparison.
"""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest
import torch

from helpers import pressed_frames
from tactile_compliance.data.normalisation import NormalisationConstants
from tactile_compliance.data.store import frames_from_uint8
from tactile_compliance.inference import (
    ComplianceEstimator,
    EnsembleEstimator,
    predict_trajectory,
    select_frame_indices,
)
from tactile_compliance.inference.ensemble import coverage, fit_interval_scale, interval_z
from tactile_compliance.inference.streaming import difference_image
from tactile_compliance.models import create_model
from tactile_compliance.physics.estimators import DEFAULT_ESTIMATOR, AnalyticalEstimator
from tactile_compliance.runs.run_inputs import RunInputs

SIZE = (40, 48)


def _estimator(inputs: str, seed: int = 0) -> ComplianceEstimator:
    torch.manual_seed(seed)
    model = create_model("top10nn", inputs=inputs)
    return ComplianceEstimator(
        model, RunInputs((72, 72), (72, 72), NormalisationConstants(), model.inputs)
    )


@pytest.fixture(scope="module")
def estimator_fw():
    return _estimator("ImageFW")


def expected_indices(force, window=None):
    """DATA_FORMATS.md: i_start = first F >= 5 N, i_peak = first F >= 0.975 F_max."""
    i_start = int(np.argmax(force >= 5.0))
    i_peak = int(np.argmax(force >= 0.975 * force.max()))
    lo = i_start if window is None else max(i_start, i_peak - window + 1)
    return tuple(int(lo + k) for k in np.linspace(0, i_peak - lo, 3).astype(int))


def feed(stream, frames, force, width, **kwargs):
    out = []
    for i in range(len(frames)):
        estimate = stream.update(frames[i], force[i], width[i], **kwargs)
        if estimate is not None:
            out.append(estimate)
    return out


def test_selection_follows_the_dataset_rule():
    _, force, _ = pressed_frames()
    selection = select_frame_indices(force)
    assert selection.indices == expected_indices(force)
    assert select_frame_indices(force, window=6).indices == expected_indices(force, window=6)
    assert select_frame_indices(np.full(20, 3.0)) is None  # never reaches 5 N
    assert select_frame_indices(np.r_[np.zeros(5), np.full(10, 8.0)]) is None  # peak < 10 N
    with pytest.raises(ValueError, match="window"):
        select_frame_indices(force, window=2)


def test_stream_reproduces_the_batch_estimate_frame_by_frame(estimator_fw):
    frames, force, width = pressed_frames()
    idx = list(expected_indices(force))
    batch = estimator_fw.predict(frames[idx], force=force[idx], width=width[idx])

    stream = estimator_fw.stream()
    emitted = feed(stream, frames, force, width)
    final = emitted[-1]
    assert final.final and stream.state == "done"
    assert final.frame_indices == tuple(idx)
    assert final.modulus_pa == pytest.approx(batch.modulus_pa, rel=1e-6)
    # Released at frame 38: the final came before the recording ended.
    assert final.frames_seen < len(frames)
    # Provisional estimates came first, from early frames, and they differ from the final
    # (so matching the final above is not a coincidence of constant outputs).
    provisional = [e for e in emitted if not e.final]
    assert len(provisional) >= 3 and not any(e.final for e in emitted[:-1])
    assert provisional[0].frames_seen <= idx[0] + 6
    assert provisional[0].modulus_pa != pytest.approx(final.modulus_pa, rel=1e-6)
    # Same thing through the whole-trajectory helper.
    whole, selection = predict_trajectory(estimator_fw, frames, force, width)
    assert selection.indices == tuple(idx)
    assert whole.modulus_pa == pytest.approx(batch.modulus_pa, rel=1e-6)
    # After the final estimate the stream ignores frames until reset.
    assert stream.update(frames[-1], force[-1], width[-1]) is None
    stream.reset()
    assert stream.state == "waiting" and stream.latest is None


def test_stream_finish_without_release_equals_batch_on_what_was_seen(estimator_fw):
    frames, force, width = pressed_frames()
    cut = 30  # in the hold, before the release
    stream = estimator_fw.stream()
    emitted = feed(stream, frames[:cut], force[:cut], width[:cut])
    assert emitted and not any(e.final for e in emitted)
    final = stream.finish()
    idx = list(expected_indices(force[:cut]))
    batch = estimator_fw.predict(frames[idx], force=force[idx], width=width[idx])
    assert final.final and final.frame_indices == tuple(idx)
    assert final.modulus_pa == pytest.approx(batch.modulus_pa, rel=1e-6)


@pytest.mark.parametrize("window", [3, 5, 9])
def test_window_uses_the_last_n_frames_up_to_the_peak(estimator_fw, window):
    frames, force, width = pressed_frames()
    stream = estimator_fw.stream(window=window)
    final = feed(stream, frames, force, width)[-1]
    idx = list(expected_indices(force, window=window))
    assert final.final and final.frame_indices == tuple(idx)
    assert idx[2] - idx[0] == window - 1
    batch = estimator_fw.predict(frames[idx], force=force[idx], width=width[idx])
    assert final.modulus_pa == pytest.approx(batch.modulus_pa, rel=1e-6)
    # The window keeps memory bounded: only frames from the window start are buffered.
    assert len(stream._buffer.frames) <= len(frames) - idx[0]


def test_stream_of_raw_frames_differences_against_the_reference(estimator_fw):
    diff_frames, force, width = pressed_frames()
    rng = np.random.default_rng(3)
    background = rng.integers(60, 190, size=(*SIZE, 3), dtype=np.uint8)
    raw = np.clip(
        background[None].astype(np.int16) + diff_frames.astype(np.int16) - 128, 0, 255
    ).astype(np.uint8)
    idx = list(expected_indices(force))
    # Difference images by hand: (frame - GaussianBlur11x11(reference)) / 255 + 0.5; the
    # module's uint8 version must decode to it within half a grey level.
    blurred = cv2.GaussianBlur(raw[0], (11, 11), 0).astype(np.float32)
    by_hand = np.stack([(raw[i].astype(np.float32) - blurred) / 255 + 0.5 for i in idx])
    differenced = np.stack([difference_image(raw[i], raw[0]) for i in idx])
    assert differenced.dtype == np.uint8
    np.testing.assert_allclose(frames_from_uint8(differenced), by_hand, atol=0.5 / 255 + 1e-6)
    batch = estimator_fw.predict(differenced, force=force[idx], width=width[idx])
    stream = estimator_fw.stream(frame_kind="raw")  # reference = first frame
    final = feed(stream, raw, force, width)[-1]
    assert final.modulus_pa == pytest.approx(batch.modulus_pa, rel=1e-6)
    explicit = estimator_fw.stream(frame_kind="raw", reference=raw[0])
    final_explicit = feed(explicit, raw[1:], force[1:], width[1:])[-1]
    assert final_explicit.modulus_pa == pytest.approx(batch.modulus_pa, rel=1e-6)


def test_stream_with_estimates_for_an_all_checkpoint():
    estimator = _estimator("ALL")
    frames, force, width = pressed_frames()
    idx = list(expected_indices(force))
    estimates = [3e5, 6e5]
    batch = estimator.predict(frames[idx], force=force[idx], width=width[idx], estimates=estimates)
    final = feed(estimator.stream(estimates_pa=estimates), frames, force, width)[-1]
    assert final.modulus_pa == pytest.approx(batch.modulus_pa, rel=1e-6)
    later = estimator.stream()
    final_later = feed(later, frames, force, width, estimates_pa=estimates)[-1]
    assert final_later.modulus_pa == pytest.approx(batch.modulus_pa, rel=1e-6)
    with pytest.raises(ValueError, match="estimates"):
        feed(estimator.stream(), frames, force, width)


def _depth_maps(force, size=(60, 80), radius_px=(4.0, 6.0), peak_mm=1.2):
    """Gaussian gel imprints (mm) that widen and deepen with the force (N)."""
    yy, xx = np.mgrid[0 : size[0], 0 : size[1]]
    r2 = (yy - size[0] / 2) ** 2 + (xx - size[1] / 2) ** 2
    share = np.clip(np.asarray(force), 0, None) / 60
    return np.stack(
        [np.exp(-r2 / (2 * (radius_px[0] + radius_px[1] * s) ** 2)) * peak_mm * s for s in share]
    )


def _stream_final(stream, frames, force, width, depth):
    return [
        e
        for i in range(len(frames))
        if (e := stream.update(frames[i], force[i], width[i], depth_mm=depth[i])) is not None
    ][-1]


def test_stream_computes_estimates_from_depth_maps_with_the_contact_estimator():
    from tactile_compliance.physics.contact import analytical_estimates_pa

    estimator = _estimator("ALL")
    frames, force, width = pressed_frames()
    depth = _depth_maps(force)
    idx = list(expected_indices(force))
    span = slice(idx[0], idx[2] + 1)  # [i_start, i_peak]
    estimates = analytical_estimates_pa(force[span], width[span], depth[span])
    batch = estimator.predict(frames[idx], force=force[idx], width=width[idx], estimates=estimates)
    stream = estimator.stream(analytical_estimator=AnalyticalEstimator("contact"))
    final = _stream_final(stream, frames, force, width, depth)
    assert final.final and final.modulus_pa == pytest.approx(batch.modulus_pa, rel=1e-6)
    with pytest.raises(ValueError, match="every frame of a grasp or never"):
        stream.reset()
        stream.update(frames[0], force[0], width[0], depth_mm=depth[0])
        stream.update(frames[1], force[1], width[1])


def test_stream_computes_the_dataset_estimates_by_default():
    """No train/serve skew: a checkpoint that records no estimator, or "dataset", gets the
    public dataset's estimator, fed the recording as the dataset's driver loaded it."""
    from tactile_compliance.physics.contact import analytical_estimates_pa
    from tactile_compliance.physics.dataset_estimates import dataset_estimates_pa

    estimator = _estimator("ALL")
    assert estimator.run_inputs.estimator == DEFAULT_ESTIMATOR
    frames, force, width = pressed_frames()
    # Large imprints: the dataset's estimator needs >= 2690 px of contact on its grid.
    depth = _depth_maps(force, size=(250, 350), radius_px=(20.0, 40.0), peak_mm=1.5)
    expected = dataset_estimates_pa(force, width, depth)  # the whole recording
    assert np.all(np.isfinite(expected))
    assert not np.allclose(expected, analytical_estimates_pa(force, width, depth), rtol=0.05)
    idx = list(expected_indices(force))
    batch = estimator.predict(frames[idx], force=force[idx], width=width[idx], estimates=expected)
    final = _stream_final(estimator.stream(), frames, force, width, depth)
    assert final.final and final.modulus_pa == pytest.approx(batch.modulus_pa, rel=1e-6)
    # A checkpoint trained on "contact" values is fed "contact" values.
    contact = replace(estimator.run_inputs, estimator=AnalyticalEstimator("contact"))
    estimator.run_inputs = contact
    assert estimator.stream().analytical_estimator == AnalyticalEstimator("contact")
    with pytest.raises(ValueError, match="unknown analytical estimator"):
        AnalyticalEstimator("hertz")


def test_stream_input_errors(estimator_fw):
    frames, force, width = pressed_frames()
    stream = estimator_fw.stream()
    with pytest.raises(ValueError, match="width_m"):
        stream.update(frames[0], force[0], None)
    with pytest.raises(ValueError, match="force_n must be finite"):
        stream.update(frames[0], float("nan"), width[0])
    with pytest.raises(ValueError, match="one difference image"):
        stream.update(frames[:2], force[0], width[0])
    stream.update(frames[0], force[0], width[0])
    with pytest.raises(ValueError, match="frame shape changed"):
        stream.update(frames[1][:20], force[1], width[1])
    with pytest.raises(ValueError, match="frame shape changed"):
        stream.update(frames[1].astype(np.float32) / 255, force[1], width[1])
    with pytest.raises(ValueError, match="uint8 camera images"):
        estimator_fw.stream(frame_kind="raw").update(frames[0] / 255.0, force[0], width[0])
    # The first frame of a grasp meets predict's own rule at once, not at the press.
    fresh = estimator_fw.stream()
    with pytest.raises(ValueError, match="models need at least"):
        fresh.update(frames[0][:4, :4], force[0], width[0])
    with pytest.raises(ValueError, match="difference images in"):
        fresh.update(np.full(frames[0].shape, 3.0, np.float32), force[0], width[0])
    assert fresh.frames_seen == 0  # a refused frame is not added
    nan = frames[0].astype(np.float32) / 255
    nan[0, 0, 0] = np.nan
    with pytest.raises(ValueError, match="NaN/inf"):  # the first frame, by check_frames
        fresh.update(nan, force[0], width[0])
    fresh.update(frames[0].astype(np.float32) / 255, force[0], width[0])
    with pytest.raises(ValueError, match="NaN/inf"):  # a later one, by the stream
        fresh.update(nan, force[1], width[1])
    assert fresh.frames_seen == 1
    with pytest.raises(ValueError, match="window"):
        estimator_fw.stream(window=1)
    with pytest.raises(ValueError, match="frame_kind"):
        estimator_fw.stream(frame_kind="depth")


def test_no_contact_gives_no_estimate(estimator_fw):
    frames, force, width = pressed_frames()
    stream = estimator_fw.stream()
    assert feed(stream, frames, np.minimum(force, 4.0), width) == []
    assert stream.state == "waiting" and stream.finish() is None
    assert len(stream._buffer.frames) == 1  # nothing buffered before contact


# ---------------------------------------------------------------------- ensembles
def test_ensemble_mean_and_interval_from_members():
    members = [_estimator("ImageFW", seed=s) for s in range(3)]
    ensemble = EnsembleEstimator(members, level=0.8)
    frames, force, width = pressed_frames()
    idx = list(expected_indices(force))
    batch_frames = np.stack([frames[idx], frames[[i + 1 for i in idx]]])
    batch_force = np.stack([force[idx], force[[i + 1 for i in idx]]])
    batch_width = np.stack([width[idx], width[[i + 1 for i in idx]]])
    result = ensemble.predict(batch_frames, batch_force, batch_width)
    logs = np.stack(
        [m.predict(batch_frames, batch_force, batch_width).log10_modulus_pa for m in members]
    )
    np.testing.assert_allclose(result.log10_modulus_pa, logs.mean(0), atol=1e-12)
    np.testing.assert_allclose(result.std_decades, logs.std(0, ddof=1), atol=1e-12)
    half = 1.2815515655446004 * logs.std(0, ddof=1)
    np.testing.assert_allclose(result.interval_log10[1] - result.log10_modulus_pa, half)
    np.testing.assert_allclose(result.modulus_pa, 10 ** logs.mean(0))
    assert result.contains(result.modulus_pa).all()
    single = ensemble.predict(frames[idx], force[idx], width[idx])
    assert isinstance(single.modulus_pa, float)
    assert single.log10_modulus_pa == pytest.approx(result.log10_modulus_pa[0])
    wide = EnsembleEstimator(members, level=0.8, scale=2.0).predict(
        frames[idx], force[idx], width[idx]
    )
    assert wide.half_width_decades == pytest.approx(2 * single.half_width_decades)
    assert ensemble.required_inputs == ("frames", "force", "width")


def test_interval_scale_fit_reaches_the_level_and_no_more():
    rng = np.random.default_rng(0)
    members = rng.normal(0, 0.3, size=(5, 400)) + rng.normal(0, 1, 400)
    truth = members.mean(0) + rng.normal(0, 0.6, 400)  # wider than the members' spread
    raw = coverage(members, truth, 0.8)
    scale = fit_interval_scale(members, truth, 0.8)
    assert raw < 0.8 and scale > 1
    assert coverage(members, truth, 0.8, scale) >= 0.8
    assert coverage(members, truth, 0.8, scale * 0.98) < 0.8
    assert interval_z(0.8) == pytest.approx(1.2815515655446004)
    with pytest.raises(ValueError):
        interval_z(1.0)
    with pytest.raises(ValueError, match="at least one"):
        EnsembleEstimator([])


def test_window_study_tables(estimator_fw):
    # The study is a research script in benchmarks/, not part of the package.
    from inference_studies import summarise_window_study, window_study
    from tactile_compliance.synthetic.trajectories import GraspTrajectory

    frames, force, width = pressed_frames(seed=0, n_frames=32, release=26)
    trajectory = GraspTrajectory("obj", 0, 1e6, frames, force, width, np.array([np.nan] * 2))
    table = window_study(estimator_fw, [trajectory], windows=(None, 4))
    assert len(table) == 2 and set(table["window"]) == {0, 4}
    full = table[table["window"] == 0].iloc[0]
    idx = list(expected_indices(force))
    batch = estimator_fw.predict(frames[idx], force=force[idx], width=width[idx])
    assert full["final_log10"] == pytest.approx(batch.log10_modulus_pa, abs=1e-6)
    assert full["span"] == idx[2] - idx[0]
    summary = summarise_window_study(table).set_index("window")
    assert summary.loc["full", "final_vs_full_max_abs_decades"] == 0.0
    assert summary.loc[4, "mean_span_frames"] == 3
    assert summary.loc["full", "final_mae_decades"] == pytest.approx(
        np.mean(np.abs(table[table["window"] == 0]["final_log10"] - 6.0))
    )
