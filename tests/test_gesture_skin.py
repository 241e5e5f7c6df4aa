"""The gesture dataset kind: interchange-format and .npz folders, and their errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from frictionfit.datasets import load_dataset
from frictionfit.datasets.gesture_skin import frames_of, load, recording_from_frames, taxel_names
from frictionfit.errors import DatasetError, RecordingError
from frictionfit.recording import DatasetWarning, Recording, write_recording


def write_npz(path, frames, **keys):
    data = {"frames": frames, "rate_hz": 50.0, "label": "poke", "person": "p0", **keys}
    np.savez(path, **{k: v for k, v in data.items() if v is not None})


@pytest.fixture
def frames(rng):
    f = np.zeros((12, 3, 4))
    f[3:8, 1, 2] = rng.uniform(5, 50, size=5)
    return f


def test_taxel_names_are_row_major():
    assert taxel_names(2, 3) == ["r0c0", "r0c1", "r0c2", "r1c0", "r1c1", "r1c2"]


def test_interchange_folder_round_trip(tmp_path, frames):
    meta = {"label": "poke", "person": "anna", "repetition": 3}
    write_recording(recording_from_frames(frames, 50.0, meta, name="a"), tmp_path / "a")
    [rec] = load(tmp_path)
    np.testing.assert_array_equal(frames_of(rec), frames)
    assert rec.metadata == {**meta, "gesture": "poke"}  # gesture defaults to the label
    assert rec.problems == ()  # untouched (constant) taxels are not problems
    assert rec.channels[0].unit == "kPa"


def test_channels_in_any_order_are_put_on_the_grid(tmp_path, frames):
    rec = recording_from_frames(frames, 50.0, {"label": "x", "person": "p"})
    perm = np.random.default_rng(1).permutation(12)
    shuffled = Recording.from_arrays(
        rec.samples[:, perm], 50.0, [rec.channel_names[i] for i in perm], units="1",
        metadata=rec.metadata,
    )
    write_recording(shuffled, tmp_path / "s")
    np.testing.assert_array_equal(frames_of(load(tmp_path)[0]), frames)


def test_npz_folder_with_repetition_counted_per_person_and_gesture(tmp_path, frames):
    write_npz(tmp_path / "a.npz", frames)
    write_npz(tmp_path / "b.npz", frames, label="pinch")
    write_npz(tmp_path / "c.npz", frames * 2)
    write_npz(tmp_path / "d.npz", frames, person="p1", repetition=7,
              metadata=json.dumps({"synthetic": True}), truth=json.dumps({"tau": 0.2}))
    recs = load_dataset(f"gesture:{tmp_path}")
    assert [r.name for r in recs] == ["a", "b", "c", "d"]
    assert [r.metadata["repetition"] for r in recs] == [0, 0, 1, 7]
    assert recs[3].metadata == {"synthetic": True, "label": "poke", "person": "p1",
                                "repetition": 7, "gesture": "poke"}
    assert recs[3].truth == {"tau": 0.2}
    np.testing.assert_array_equal(frames_of(recs[2]), frames * 2)
    assert recs[0].sample_rate_hz == 50.0 and recs[0].t[1] == pytest.approx(0.02)


def test_nan_frames_are_flagged_not_hidden(tmp_path, frames):
    frames[4, 0, 0] = np.nan
    write_npz(tmp_path / "a.npz", frames)
    [rec] = load(tmp_path)
    assert [p.kind for p in rec.problems] == ["nonfinite"]
    assert rec.problems[0].channel == "r0c0"


@pytest.mark.parametrize(
    ("keys", "match"),
    [
        ({"label": None}, r"a\.npz: npz lacks \['label'\]"),
        ({"frames": np.zeros((5, 4))}, r"a\.npz: 'frames' must be time x rows x cols"),
        ({"rate_hz": -5.0}, r"a\.npz: rate_hz must be a positive number"),
        ({"rate_hz": np.array([50.0, 50.0])}, r"a\.npz: npz entry 'rate_hz' must be a scalar"),
        ({"unit": "N"}, r"a\.npz: unit 'N' is not a taxel unit"),
        ({"metadata": "{oops"}, r"a\.npz: npz entry 'metadata' is not valid JSON"),
        ({"person": ""}, r"a\.npz: metadata lacks 'person'"),
    ],
)
def test_malformed_npz_names_the_file(tmp_path, frames, keys, match):
    write_npz(tmp_path / "a.npz", keys.pop("frames", frames), **keys)
    with pytest.raises(RecordingError, match=match):
        load(tmp_path, strict=True)
    with pytest.warns(DatasetWarning, match="skipped .*" + match):  # the only file: none left
        with pytest.raises(DatasetError, match="none of its 1 gesture recordings could be read"):
            load(tmp_path)


@pytest.mark.parametrize("content", ["not a zip", ""])
def test_a_file_that_is_not_npz(tmp_path, content):
    # an empty file raised EOFError, which the command line took for Ctrl-D ("Aborted!")
    (tmp_path / "junk.npz").write_text(content)
    with pytest.raises(RecordingError, match=r"junk\.npz: cannot read npz"):
        load(tmp_path, strict=True)


def _write(tmp_path, names, units="kPa", meta=None):
    rec = Recording.from_arrays(
        np.arange(2.0 * len(names)).reshape(2, -1) + np.arange(len(names)), 50.0, names,
        units=units, metadata={"label": "poke", "person": "p0"} if meta is None else meta,
    )
    write_recording(rec, tmp_path / "g")


@pytest.mark.parametrize(
    ("names", "units", "match"),
    [
        (["r0c0", "fx"], "kPa", r"g\.csv: channel 'fx': channel name is not a taxel name"),
        (["r0c0", "r0c1"], "N", r"g\.csv: channel 'r0c0': unit 'N' is not a taxel unit"),
        (["r0c0", "r1c1"], "kPa", r"g\.csv: taxel matrix 2 x 2 is incomplete: 2 taxel"),
    ],
)
def test_malformed_interchange_names_file_and_channel(tmp_path, names, units, match):
    _write(tmp_path, names, units)
    with pytest.raises(RecordingError, match=match):
        load(tmp_path, strict=True)


def test_duplicate_taxel_in_memory():
    rec = Recording.from_arrays(np.ones((3, 2)), 50.0, ["r0c0", "r00c0"], units="kPa", name="dup")
    with pytest.raises(RecordingError, match=r"dup: channel 'r0c0': taxel appears twice"):
        frames_of(rec)


def test_missing_label_in_sidecar(tmp_path):
    _write(tmp_path, ["r0c0", "r0c1"], meta={"person": "p0"})
    with pytest.raises(RecordingError, match=r"g\.csv: metadata lacks 'label'"):
        load(tmp_path, strict=True)


def test_folder_errors(tmp_path, frames):
    with pytest.raises(DatasetError, match="not a folder of gesture recordings"):
        load(tmp_path / "nowhere")
    with pytest.raises(DatasetError, match="no gesture recordings"):
        load(tmp_path, strict=True)
    write_npz(tmp_path / "a.npz", frames)
    write_npz(tmp_path / "b.npz", np.zeros((12, 4, 4)))
    with pytest.raises(DatasetError, match=r"b\.npz: taxel matrix \(4, 4\) differs from \(3, 4\)"):
        load(tmp_path, strict=True)


def test_recording_from_frames_needs_3d():
    with pytest.raises(RecordingError, match=r"frames must be 3-D \(time x rows x cols\)"):
        recording_from_frames(np.zeros((4, 4)), 50.0, {})
