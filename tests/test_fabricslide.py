"""FabricSlide loader: names, timestamps, channels, metadata, malformed files, subsets."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from frictionfit.datasets import load_dataset
from frictionfit.datasets.fabricslide import (
    COLUMNS,
    PROXIMITY,
    TAXELS,
    load,
    parse_name,
    read_slide,
    slide_duration_s,
)
from frictionfit.errors import DatasetError, RecordingError
from frictionfit.recording import DatasetWarning

HEADER = ", ".join(COLUMNS)


def write_slide(path: Path, n: int = 40, start_ms: int = 5000, step_ms=None,
                rng=None) -> np.ndarray:
    """A small file in the upstream format ("a, b" with spaces); returns its value rows.

    ``step_ms=None``: rows spread over the whole slide its name's speed implies."""
    rng = rng or np.random.default_rng(0)
    if step_ms is None:
        step_ms = int(np.ceil(1000 * slide_duration_s(parse_name(path)["speed"]) / (n - 1)))
    ts = start_ms + np.cumsum(np.r_[0, np.broadcast_to(step_ms, (n - 1,))])
    prox = np.column_stack([rng.integers(0, 100, n), np.full(n, 65535)])
    taxels = rng.integers(20, 600, size=(n, 16))
    rows = np.column_stack([ts, prox, taxels]).astype(int)
    path.write_text(HEADER + "\n" + "\n".join(", ".join(map(str, r)) for r in rows) + "\n")
    return rows


def _replace_field(line: str, i: int, value: str) -> str:
    fields = line.split(", ")
    fields[i] = value
    return ", ".join(fields)


def test_parse_name_reads_fabric_pressure_speed_and_repetition():
    meta = parse_name("Linen_F180_V-10mmps_1.csv")
    assert meta == {"fabric": "Linen", "pressure": 180, "speed": -10, "direction": "down",
                    "repetition": 1, "condition": "F180_V-10"}
    assert parse_name("DenimFlex_F120_V150mmps_0.csv")["direction"] == "up"


@pytest.mark.parametrize(
    "name", ["Linen_F180_10mmps_0.csv", "Linen.csv", "Linen_F180_V0mmps_0.csv"]
)
def test_parse_name_rejects_bad_names(name):
    with pytest.raises(RecordingError, match=rf"{name}: .*(file name|speed 0)"):
        parse_name(name)


def test_read_slide_converts_times_channels_and_metadata(tmp_path):
    rows = write_slide(tmp_path / "Canvas_F150_V-50mmps_0.csv", step_ms=[28, 29] * 19 + [28])
    rec = read_slide(tmp_path / "Canvas_F150_V-50mmps_0.csv")
    assert rec.channel_names == (*TAXELS, *PROXIMITY)
    assert {c.unit for c in rec.channels} == {"counts"}
    np.testing.assert_allclose(rec.t, (rows[:, 0] - rows[0, 0]) / 1000.0)
    np.testing.assert_array_equal(rec.channel("channel7"), rows[:, 3 + 6])
    np.testing.assert_array_equal(rec.channel("proximity1"), rows[:, 1])
    assert rec.sample_rate_hz == pytest.approx(1000.0 / 28.5, rel=1e-3)
    assert rec.label == "Canvas"
    meta = rec.metadata
    assert (meta["pressure"], meta["speed"], meta["repetition"]) == (150, -50, 0)
    assert meta["dataset"] == "fabricslide"
    assert meta["ramp_s"] == pytest.approx(47.1 / 50)
    assert meta["logger_start_ms"] == 5000


def test_repeated_last_row_is_dropped_and_reported(tmp_path):
    path = tmp_path / "Linen_F120_V20mmps_0.csv"
    write_slide(path)
    lines = path.read_text().splitlines()
    path.write_text("\n".join([*lines, lines[-1]]) + "\n")
    rec = read_slide(path)
    assert rec.n_samples == 40
    assert [p.kind for p in rec.problems] == ["duplicate_row"]


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda lines: [lines[0].replace("channel16", "chan16"), *lines[1:]],
         r"missing column\(s\) \['channel16'\]"),
        (lambda lines: [*lines[:5], _replace_field(lines[5], 1, "x"), *lines[6:]],
         r"channel 'proximity1': non-numeric value 'x' at data row 5"),
        (lambda lines: [*lines[:20], lines[20][: len(lines[20]) // 2]],
         r"channel 'channel\d+': missing value \(a row cut short\?\) at data row 20"),
        (lambda lines: [*lines[:3], lines[4], lines[3], *lines[5:]],
         r"channel 'timestamp': timestamp not increasing at data row 4 \(5084 ms then 5056 ms\)"),
        (lambda lines: lines[:10], r"only 9 rows"),
        (lambda lines: [], r"the file is empty"),
    ],
)
def test_malformed_files_are_rejected_naming_file_and_problem(tmp_path, edit, message):
    path = tmp_path / "Denim_F210_V-100mmps_1.csv"
    write_slide(path, step_ms=28)
    path.write_text("\n".join(edit(path.read_text().splitlines())) + "\n")
    with pytest.raises(RecordingError, match=rf"Denim_F210_V-100mmps_1.csv: .*{message}"):
        read_slide(path)


def test_folder_load_raises_or_skips_a_bad_file(tmp_path):
    write_slide(tmp_path / "Linen_F120_V10mmps_0.csv")
    write_slide(tmp_path / "Canvas_F120_V10mmps_0.csv")
    (tmp_path / "notes.csv").write_text("timestamp\n1\n")
    with pytest.raises(RecordingError, match="notes.csv: file name does not follow"):
        load(tmp_path, strict=True)
    with pytest.warns(DatasetWarning, match="skipped .*notes.csv"):
        recs = load(tmp_path)
    assert [r.name for r in recs] == ["Canvas_F120_V10mmps_0", "Linen_F120_V10mmps_0"]
    assert len(load_dataset(f"fabricslide:{tmp_path / 'Linen_F120_V10mmps_0.csv'}")) == 1


def test_a_slide_cut_short_is_flagged_and_left_out(tmp_path):
    path = tmp_path / "Linen_F120_V20mmps_0.csv"
    write_slide(path, n=60)
    lines = path.read_text().splitlines()
    path.write_text("\n".join(lines[:41]) + "\n")  # 40 of 60 rows: 2/3 of the slide
    rec = read_slide(path)
    assert [str(p) for p in rec.problems] == [
        f"the slide ends after {rec.t[-1]:.1f} s; at 20 mm/s it lasts 29.7 s (file cut short?)"]
    write_slide(tmp_path / "Canvas_F120_V20mmps_0.csv")
    with pytest.warns(DatasetWarning, match=r"skipped .*Linen_F120_V20mmps_0.csv: the slide ends "
                      r"after \d+\.\d s; at 20 mm/s it lasts 29\.7 s"):
        assert [r.name for r in load(tmp_path)] == ["Canvas_F120_V20mmps_0"]
    with pytest.raises(RecordingError, match="Linen_F120_V20mmps_0.csv: the slide ends after"):
        load(tmp_path, strict=True)
    from typer.testing import CliRunner

    from frictionfit.cli import app

    result = CliRunner().invoke(app, ["info", f"fabricslide:{tmp_path}"])
    assert result.exit_code == 0, result.output
    assert "Linen_F120_V20mmps_0.csv: the slide ends after" in result.output
    assert "using 1 recordings; 1 skipped" in result.output and ": 1 recordings" in result.output
    result = CliRunner().invoke(app, ["info", f"fabricslide:{tmp_path}", "--strict"])
    assert result.exit_code == 1 and "the slide ends after" in result.output


def test_empty_or_missing_folder_is_a_dataset_error(tmp_path):
    with pytest.raises(DatasetError, match="no FabricSlide recordings"):
        load(tmp_path)
    with pytest.raises(DatasetError, match="no such FabricSlide folder"):
        load(tmp_path / "absent")


@pytest.mark.shared
def test_shared_subset_loads_with_documented_rate_and_lengths(shared, tmp_path):
    src = shared / "datasets" / "fabricslide"
    names = ["BeigeCotton_F120_V20mmps_0.csv", "Denim_F210_V-150mmps_1.csv",
             "WovenFabric_F180_V-10mmps_0.csv"]
    for name in names:  # a subset folder, by links: nothing is copied
        (tmp_path / name).symlink_to(src / name)
    recs = load(tmp_path)
    assert [r.n_samples for r in recs] == [1060 - 1, 142, 2116]  # first: repeated row dropped
    for rec in recs:
        assert rec.sample_rate_hz == pytest.approx(35.6, rel=0.01)
        assert np.all(np.diff(rec.t) > 0.026) and np.all(np.diff(rec.t) < 0.030)
        assert rec.duration_s == pytest.approx(594.2 / abs(rec.metadata["speed"]), rel=0.02)
    assert recs[0].problems[0].kind == "duplicate_row"
