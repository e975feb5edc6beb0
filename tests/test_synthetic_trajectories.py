"""render_recording: every frame of a grasp, consistent with the stored frames."""

import numpy as np
import pytest

from tactile_compliance.synthetic.grasp import (
    SimulationOptions,
    make_context,
    render_recording,
)
from tactile_compliance.synthetic.objects import default_objects
from tactile_compliance.synthetic.trajectories import synthetic_trajectories

SIZE = (60, 80)


def _correlation(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.corrcoef(a.ravel() - 0.5, b.ravel() - 0.5)[0, 1])


@pytest.mark.parametrize("finger", [0, 1])
def test_recording_matches_the_stored_frames_up_to_noise(finger: int) -> None:
    spec = default_objects(3, seed=4)[0]
    ctx = make_context(spec, 4, SimulationOptions(image_size=SIZE))
    result, recording = render_recording(ctx, 0, finger)
    assert result.samples, "this grasp is accepted by the frame selection"
    assert recording.shape == (result.timeline.force_n.size, *SIZE, 3)
    video = result.selection.fingers[finger]
    stored = result.samples[0].rgb if finger == 0 else result.samples[0].rgb_markers
    other = result.samples[0].rgb_markers if finger == 0 else result.samples[0].rgb
    same = _correlation(recording[video], stored)
    assert same > 0.85  # same pose, sensor and texture; only the read noise differs
    assert same > _correlation(recording[video], other) + 0.1  # not the other finger


def test_recording_rejects_a_bad_finger() -> None:
    ctx = make_context(default_objects(1, seed=0)[0], 0, SimulationOptions(image_size=SIZE))
    with pytest.raises(ValueError, match="finger"):
        render_recording(ctx, 0, finger=2)


def test_synthetic_trajectories_carry_the_whole_time_line() -> None:
    names = [s.name for s in default_objects(3, seed=4)]
    trajectories = list(
        synthetic_trajectories([(names[0], 0), (names[1], 1)], n_objects=3, seed=4, image_size=SIZE)
    )
    assert trajectories
    for t in trajectories:
        assert t.frames.dtype == np.uint8 and t.frames.shape[1:] == (*SIZE, 3)
        assert t.frames.shape[0] == t.force_n.size == t.width_m.size
        assert np.isfinite(t.force_n).all() and t.force_n.max() > 10.0
