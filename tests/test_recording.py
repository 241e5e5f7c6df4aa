"""The interchange format: round trip and every bad-input path, tested by its words."""

import json

import numpy as np
import pytest

from frictionfit.errors import DatasetError, RecordingError
from frictionfit.recording import (
    DatasetWarning,
    Event,
    Recording,
    Rig,
    check_newtons,
    read_dataset,
    read_recording,
    write_recording,
)

CHANNELS = ["thumb_x", "thumb_y", "index_x", "index_y"]


def _rec(rng, n=500, name="s1_paper-2_01", extra=None):
    x = np.round(rng.standard_normal((n, 4)), 3)
    return Recording.from_arrays(
        x, 1000.0, CHANNELS, name=name,
        events=[Event(0.05, "move", "p2"), Event(0.3, "move", "p1")],
        metadata={"label": "paper-2", "material": "paper", "layers": 2, "session": 1,
                  "trial": 1, "free": {"a": 1}},
        truth={"k": 3.0}, extra={"acquisition": {"frames_valid": 10}, **(extra or {})},
    )


def test_round_trip_is_exact(tmp_path, rng):
    rec = _rec(rng)
    write_recording(rec, tmp_path / rec.name)
    back = read_recording(tmp_path / f"{rec.name}.csv")
    assert np.array_equal(back.samples, rec.samples) and np.array_equal(back.t, rec.t)
    assert back.metadata == rec.metadata and back.truth == rec.truth
    assert back.events == rec.events and back.channels == rec.channels
    assert back.extra == rec.extra


def test_events_listed_out_of_order_are_read_in_time_order(tmp_path, rng):
    rec = _rec(rng)
    write_recording(rec, tmp_path / "r")
    side = json.loads((tmp_path / "r.json").read_text())
    side["events"].reverse()
    (tmp_path / "r.json").write_text(json.dumps(side))
    assert read_recording(tmp_path / "r").events == rec.events


def test_motor_positions_round_trip_at_their_own_times(tmp_path, rng):
    block = {"columns": [{"name": "t_request", "unit": "s"}, {"name": "t_reply", "unit": "s"},
                         {"name": "position", "unit": "counts"}],
             "reads": [[0.01, 0.03, 1000.0], [0.052, 0.07, 1003.0], [0.25, 0.27, 1200.0]],
             "counts_per_revolution": 4096, "rate_hz_requested": 50.0, "reads_failed": 1}
    rec = _rec(rng, extra={"motor_positions": block})
    assert _rec(rng).motor_positions() is None
    write_recording(rec, tmp_path / "r", decimals=3)
    back = read_recording(tmp_path / "r")
    assert back.extra["motor_positions"] == block
    t, position = back.motor_positions()
    np.testing.assert_allclose(t, [0.02, 0.061, 0.26])  # the middle of each read
    np.testing.assert_array_equal(position, [1000.0, 1003.0, 1200.0])


def test_malformed_motor_positions_name_the_recording(rng):
    rec = _rec(rng, extra={"motor_positions": {"columns": [{"name": "t"}], "reads": [[0.1]]}})
    with pytest.raises(RecordingError, match="s1_paper-2_01.*malformed 'motor_positions'"):
        rec.motor_positions()


def test_round_trip_with_millinewton_decimals(tmp_path, rng):
    rec = _rec(rng)
    write_recording(rec, tmp_path / "r", decimals=3)
    assert np.array_equal(read_recording(tmp_path / "r").samples, rec.samples)


def _write_bad(tmp_path, rng, mutate_csv=None, mutate_json=None):
    rec = _rec(rng)
    write_recording(rec, tmp_path / "bad")
    if mutate_csv:
        p = tmp_path / "bad.csv"
        p.write_text(mutate_csv(p.read_text()))
    if mutate_json:
        p = tmp_path / "bad.json"
        side = json.loads(p.read_text())
        mutate_json(side)
        p.write_text(json.dumps(side))
    return tmp_path / "bad"


def _swap_rows(text):
    lines = text.splitlines()
    lines[3], lines[4] = lines[4], lines[3]
    return "\n".join(lines) + "\n"


def _nan_in_index_x(text):
    lines = text.splitlines()
    for i in range(10, 20):
        cells = lines[i].split(",")
        cells[3] = "nan"
        lines[i] = ",".join(cells)
    return "\n".join(lines) + "\n"


def _dead_thumb_y(text):
    lines = text.splitlines()
    for i in range(1, len(lines)):
        cells = lines[i].split(",")
        cells[2] = "0.5"
        lines[i] = ",".join(cells)
    return "\n".join(lines) + "\n"


def _cell_abc(text):
    lines = text.splitlines()
    cells = lines[5].split(",")
    cells[3] = "abc"
    lines[5] = ",".join(cells)
    return "\n".join(lines) + "\n"


def _semicolons(text):
    return text.replace(",", ";")


def _header_only(text):
    return text.splitlines()[0] + "\n"


def _nan_in_t(text):
    lines = text.splitlines()
    lines[7] = "nan" + lines[7][lines[7].index(","):]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize(
    "mutate_csv, mutate_json, match",
    [
        (_swap_rows, None, r"bad\.csv: time is not strictly increasing at row"),
        (_dead_thumb_y, None, r"channel 'thumb_y': constant at 0\.5 N \(dead\?\)"),
        (None, lambda s: s.update(sample_rate_hz=500.0), r"does not match sample_rate_hz=500"),
        (None, lambda s: s.pop("channels"), r"bad\.json: sidecar is missing the field 'channels'"),
        (None, lambda s: s.update(sample_rate_hz=-1), r"sample_rate_hz must be a positive"),
        (None, lambda s: s["channels"][0].update(name="thumb_z"), r"CSV columns .* do not match"),
        (None, lambda s: s["channels"][1].update(unit="furlong"), r"'thumb_y': unknown unit"),
        (None, lambda s: s["channels"][1].pop("unit"), r"channels\[1\] needs 'name' and 'unit'"),
        (None, lambda s: s["events"].append({"kind": "move"}), r"malformed event"),
        (None, lambda s: s.update(sample_rate_hz=True), r"bad\.json: sample_rate_hz must be a "
         r"positive number, not True"),
        (None, lambda s: s.update(metadata=[1, 2]), r"bad\.json: sidecar field 'metadata' must be "
         r"an object, not \[1, 2\]"),
        (None, lambda s: s.update(metadata=None), r"'metadata' must be an object, not null"),
        (None, lambda s: s.update(channels=4), r"bad\.json: sidecar field 'channels' must be a "
         r"list, not 4"),
        (_cell_abc, None, r"bad\.csv: cannot parse CSV: data row 5 \(line 6\), column "
         r"'index_x': 'abc' is not a number"),
        (_semicolons, None, r"bad\.csv: .*looks separated by ';'; frictionfit reads "
         r"comma-separated values"),
        (_header_only, None, r"bad\.csv: only 0 sample\(s\)"),
        (_nan_in_t, None, r"bad\.csv: column 't' has NaN/inf values"),
        (None, lambda s: s.update(events=[dict(e, t=e["t"] + 1.7e9) for e in s["events"]]),
         r"bad\.csv: \d+ event\(s\) outside the recording's time range .* seconds from the "
         r"start"),
    ],
)
def test_bad_input_names_file_channel_and_problem(tmp_path, rng, mutate_csv, mutate_json, match):
    path = _write_bad(tmp_path, rng, mutate_csv, mutate_json)
    with pytest.raises(RecordingError, match=match):
        read_recording(path)


@pytest.mark.parametrize(("names", "words"), [
    (["a", "a"], "channel name 'a' appears twice"),
    (["a,b", "c"], "channel name 'a,b' holds a comma, quote or line break"),
    (["t", "c"], "channel name 't' is the time column's"),
    ([" a", "c"], "channel name ' a' starts or ends with a space"),
    (["", "c"], "channel name '' is empty"),
])
def test_channel_names_a_csv_cannot_hold_back_are_refused(tmp_path, names, words):
    with pytest.raises(RecordingError, match=words):
        Recording.from_arrays(np.zeros((3, 2)), 1000.0, names)


def test_nan_samples_are_listed_not_raised_a_lab_link_loses_samples(tmp_path, rng):
    rec = read_recording(_write_bad(tmp_path, rng, mutate_csv=_nan_in_index_x))
    assert [str(p) for p in rec.problems] == [
        "channel 'index_x': 10 NaN/inf sample(s), first at t=0.009 s"]
    assert not rec.disqualified


def test_flag_policy_keeps_data_and_lists_problems(tmp_path, rng):
    path = _write_bad(tmp_path, rng, mutate_csv=_nan_in_index_x)
    rec = read_recording(path, on_error="flag")
    assert [p.kind for p in rec.problems] == ["nonfinite"]
    assert rec.problems[0].channel == "index_x"
    assert np.isnan(rec.channel("index_x")).sum() == 10


def test_missing_sidecar_and_data_file(tmp_path, rng):
    write_recording(_rec(rng), tmp_path / "r")
    (tmp_path / "r.json").unlink()
    with pytest.raises(RecordingError, match=r"r\.json: sidecar file is missing"):
        read_recording(tmp_path / "r.csv")
    write_recording(_rec(rng), tmp_path / "q")
    (tmp_path / "q.csv").unlink()
    with pytest.raises(RecordingError, match=r"q\.csv: data file is missing"):
        read_recording(tmp_path / "q")
    with pytest.raises(RecordingError, match=r"typo\.csv: no such recording"):
        read_recording(tmp_path / "typo.csv")
    (tmp_path / "fits.parquet").write_bytes(b"PAR1")
    with pytest.raises(RecordingError, match=r"fits\.parquet: not a recording: frictionfit "
                                             r"reads <name>\.csv with its <name>\.json"):
        read_recording(tmp_path / "fits.parquet")


def test_spaces_after_the_commas_are_read(tmp_path, rng):
    rec = _rec(rng)
    write_recording(rec, tmp_path / "r")
    csv = tmp_path / "r.csv"
    csv.write_text(csv.read_text().replace(",", ", "))
    back = read_recording(csv)
    assert back.channel_names == rec.channel_names
    np.testing.assert_array_equal(back.samples, rec.samples)


def test_a_name_with_dots_keeps_them(tmp_path, rng):
    rec = _rec(rng, name="run_1.5mm")
    assert write_recording(rec, tmp_path / "run_1.5mm").name == "run_1.5mm.csv"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run_1.5mm.csv", "run_1.5mm.json"]
    for path in ("run_1.5mm", "run_1.5mm.csv", "run_1.5mm.json"):
        assert read_recording(tmp_path / path).name == "run_1.5mm"


def test_a_recording_cut_short_is_used_and_named(tmp_path, rng):
    # an interrupted acquisition: the commands it sent reach past its last flushed row
    rec = _rec(rng)
    late = Recording(rec.t, rec.samples, 1000.0, rec.channels,
                     events=(*rec.events, Event(0.55, "move", "p2"), Event(0.8, "move", "p1")))
    write_recording(late, tmp_path / "cut")
    back = read_recording(tmp_path / "cut")
    assert not back.disqualified
    assert [str(p) for p in back.problems] == [
        "2 event(s) after the last sample at t=0.499 s, first move p2 at t=0.55 s: the "
        "recording stops before its protocol did (an interrupted acquisition?); what it holds "
        "is used"]
    # every event outside (another clock) or one before the start still disqualifies
    for events in ((Event(0.6, "move", "p2"),), (Event(-0.1, "move", "p2"), *rec.events)):
        write_recording(Recording(rec.t, rec.samples, 1000.0, rec.channels, events=events),
                        tmp_path / "bad")
        with pytest.raises(RecordingError, match=r"bad\.csv: \d event\(s\) outside the "
                                                 r"recording's time range"):
            read_recording(tmp_path / "bad")


def test_time_in_milliseconds_is_named(tmp_path, rng):
    rec = _rec(rng)
    write_recording(Recording(rec.t * 1e3, rec.samples, 1000.0, rec.channels), tmp_path / "ms")
    with pytest.raises(RecordingError, match=r"ms\.csv: median sample interval 1000 ms does "
                                             r"not match .* \(is t in milliseconds\? it must "
                                             r"be seconds\)"):
        read_recording(tmp_path / "ms")


def test_time_stamps_that_jitter_onto_a_neighbours_slot_are_counted(tmp_path, rng):
    rec = _rec(rng)
    t = rec.t.copy()
    t[100:400:50] += 0.6e-3  # six samples pushed onto the next sample's slot
    write_recording(Recording(t, rec.samples, 1000.0, rec.channels), tmp_path / "j")
    back = read_recording(tmp_path / "j")  # informational: the grid keeps one per slot
    assert [str(p) for p in back.problems if p.kind == "jitter"] == [
        "6 sample(s) share a slot of the 1000-Hz grid with a neighbour (their time stamps "
        "jitter by half a sample interval or more): one sample of each slot is used"]


def test_gaps_are_reported_not_raised(tmp_path, rng):
    rec = _rec(rng)
    keep = np.r_[0:100, 150:500]
    write_recording(Recording(rec.t[keep], rec.samples[keep], 1000.0, rec.channels), tmp_path / "g")
    back = read_recording(tmp_path / "g")
    assert [p.kind for p in back.problems] == ["gap"]
    assert "about 50 dropped sample(s)" in back.problems[0].detail


def test_a_folder_skips_each_unusable_file_by_name_and_strict_stops(tmp_path, rng):
    for name in ("a", "c", "d"):
        write_recording(_rec(rng, name=name), tmp_path / name)
    (tmp_path / "c.csv").write_text(_cell_abc((tmp_path / "c.csv").read_text()))
    side = json.loads((tmp_path / "d.json").read_text())
    side["sample_rate_hz"] = 500.0
    (tmp_path / "d.json").write_text(json.dumps(side))
    with pytest.warns(DatasetWarning) as caught:
        assert [r.name for r in read_dataset(tmp_path)] == ["a"]
    said = [str(w.message) for w in caught]
    assert any("c.csv: cannot parse CSV: data row 5" in m for m in said)
    assert any("d.csv: median sample interval 1 ms does not match sample_rate_hz=500" in m
               for m in said)
    with pytest.raises(DatasetError, match=r"c\.csv: cannot parse CSV"):
        read_dataset(tmp_path, strict=True)


def test_forces_in_millinewtons_are_read_in_newtons(tmp_path, rng):
    rec = _rec(rng)
    milli = Recording(rec.t, rec.samples * 1e3, 1000.0,
                      tuple(type(c)(c.name, "mN") for c in rec.channels))
    write_recording(milli, tmp_path / "m")
    back = read_recording(tmp_path / "m")
    assert {c.unit for c in back.channels} == {"N"}
    np.testing.assert_allclose(back.samples, rec.samples, rtol=1e-15)
    with pytest.raises(RecordingError, match=r"m: channel 'thumb_x': unit 'mN', not N: a "
                                             r"fit's parameters are forces in N"):
        check_newtons("m", milli.channels)
    check_newtons("m", back.channels)


def test_dataset_units_must_agree(tmp_path, rng):
    write_recording(_rec(rng, name="a"), tmp_path / "a")
    other = _rec(rng, name="b")
    other = Recording(other.t, other.samples, 1000.0,
                      tuple(type(c)(c.name, "counts") for c in other.channels))
    write_recording(other, tmp_path / "b")
    words = (r"b\.csv: channels \['thumb_x \[counts\]'.* differ from \['thumb_x \[N\]'.*units "
             r"mis")
    with pytest.raises(DatasetError, match=words):
        read_dataset(tmp_path, strict=True)
    with pytest.warns(DatasetWarning, match="skipped .*" + words):
        assert [r.name for r in read_dataset(tmp_path)] == ["a"]
    with pytest.raises(DatasetError, match=r"a\.csv: not a folder of recordings"):
        read_dataset(tmp_path / "a.csv")
    (tmp_path / "empty").mkdir()
    with pytest.raises(DatasetError, match=r"empty: no <name>\.csv \+ <name>\.json recordings"):
        read_dataset(tmp_path / "empty")


def test_lab_dataset_reads_with_problems_flagged(shared):
    recs = read_dataset(shared / "datasets" / "rubbing-lab")
    assert len(recs) == 420
    assert {r.label for r in recs} and len({r.label for r in recs}) == 35
    assert any(p.kind == "nonfinite" for r in recs for p in r.problems)


def test_rig_facts_are_read_from_the_metadata(tmp_path, rng):
    rec = _rec(rng)
    assert rec.rig == Rig() and rec.stroke_mm is None  # nothing declared: nothing assumed
    rec.metadata.update(rig="lab-2", stroke_mm=9, grip_force_n=1.5,
                        motor_positions_counts={"p1": 1800, "p2": 2300})
    write_recording(rec, tmp_path / rec.name)
    back = read_recording(tmp_path / rec.name)
    assert back.rig == Rig("lab-2", 9.0, 1.5, {"p1": 1800.0, "p2": 2300.0})
    assert back.stroke_mm == 9.0 and isinstance(back.stroke_mm, float)


@pytest.mark.parametrize("key, value, match", [
    ("stroke_mm", 0, r"metadata\.stroke_mm must be a positive number, not 0"),
    ("stroke_mm", "13 mm", r"metadata\.stroke_mm must be a positive number, not '13 mm'"),
    ("stroke_mm", True, r"metadata\.stroke_mm must be a positive number"),
    ("grip_force_n", -1.0, r"metadata\.grip_force_n must be a positive number, not -1\.0"),
    ("rig", 2, r"metadata\.rig must be a name"),
    ("motor_positions_counts", [1, 2], r"motor_positions_counts must map target names"),
])
def test_bad_rig_facts_name_the_file_and_key(tmp_path, rng, key, value, match):
    rec = _rec(rng)
    rec.metadata[key] = value
    write_recording(rec, tmp_path / rec.name)
    with pytest.raises(RecordingError, match=f"{rec.name}.json.*{match}"):
        read_recording(tmp_path / rec.name)
    with pytest.raises(RecordingError, match=match):
        _ = rec.rig


def test_the_lab_datasets_declare_their_strokes(shared):
    for folder, stroke in (("rubbing-lab", 13.0), ("rubbing-lab-B", 9.0)):
        path = next((shared / "datasets" / folder).glob("*.json"))
        rec = read_recording(path, on_error="flag")
        assert rec.stroke_mm == stroke and rec.rig.name == folder


def test_a_session_is_its_rigs():
    from frictionfit.recording import within_rig

    assert within_rig({"session": 1, "rig": "lab-B"}) == "lab-B/1"
    assert within_rig({"session": 1}) == 1
    assert within_rig({"rig": "lab-B"}) is None
    assert within_rig({"person": "p3", "rig": "skin"}, "person") == "skin/p3"
