"""Segmentation by events: motion windows, dropped samples back on the grid as NaN."""

import numpy as np
import pytest

from frictionfit.errors import RecordingError
from frictionfit.recording import Event, Recording
from frictionfit.segmentation import moving_average, regrid, segment


def _measurement(n_motions=3, rate=1000.0):
    n = int(2 * n_motions * rate)
    samples = np.arange(n, dtype=float)[:, None] * [1.0, -1.0]
    events = [Event(0.05 + 2 * k + dt, "move", tgt)
              for k in range(n_motions) for dt, tgt in ((0.0, "p2"), (1.0, "p1"))]
    return Recording.from_arrays(samples, rate, ["index_x", "thumb_x"], events=events,
                                 metadata={"label": "paper-1"})


def test_motions_start_pre_s_before_each_out_command():
    motions = segment(_measurement())
    assert [m.index for m in motions] == [1, 2]  # motion 0 (preparatory) dropped
    m = motions[0]
    assert m.t_out == pytest.approx(0.05) and m.t_back == pytest.approx(1.05)
    assert m.samples[0, 0] == 2000.0 and m.samples.shape == (2000, 2)
    assert [p.kind for p in m.phases] == ["move_out", "relax_out", "move_back", "relax_back"]
    assert m.metadata == {"label": "paper-1", "motion": 1}


def test_dropped_samples_become_nan_on_the_grid():
    rec = _measurement()
    keep = np.r_[0:2500, 2600:rec.n_samples]
    rec = Recording(rec.t[keep], rec.samples[keep], 1000.0, rec.channels, rec.events)
    t, grid = regrid(rec)
    assert grid.shape[0] == 6000 and np.isnan(grid[2500:2600]).all()
    m = segment(rec)[0]
    assert np.isnan(m.samples[500:600, 0]).all()
    assert np.isfinite(m.samples[:500]).all() and np.isfinite(m.samples[600:]).all()


def test_moving_average_ignores_nan():
    x = np.array([1.0, 2.0, np.nan, 4.0, 5.0])
    np.testing.assert_allclose(moving_average(x, 3), [1.5, 1.5, 3.0, 4.5, 4.5])


def test_no_events_is_a_named_error():
    rec = Recording.from_arrays(np.zeros((100, 1)), 1000.0, ["x"],
                                name="s1_x_01")
    with pytest.raises(RecordingError, match="s1_x_01: no 'move p2' events and no movements"):
        segment(rec)
