"""``frictionfit demo`` runs on the shipped sample data, which the documented command remakes."""

from pathlib import Path

import pytest
from typer.testing import CliRunner

from frictionfit.cli import app
from frictionfit.cli.demo import SAMPLE, SAMPLE_COMMAND
from frictionfit.simulation.measurements import simulate_dataset

DATA = Path(__file__).resolve().parents[1] / "data"


def test_sample_data_is_remade_by_the_documented_command(tmp_path):
    assert SAMPLE_COMMAND.split("--classes ")[1] == ",".join(SAMPLE["classes"])
    assert f"--motor-positions {SAMPLE['position_rate_hz']:g} " in SAMPLE_COMMAND
    shipped = sorted(p.name for p in DATA.glob("*.csv"))
    assert shipped == sorted(f"s1_{c}_01.csv" for c in SAMPLE["classes"])
    assert sum(p.stat().st_size for p in DATA.iterdir()) < 2e6
    # a measurement does not depend on the other classes simulated with it
    path, = simulate_dataset(tmp_path, SAMPLE["seed"], SAMPLE["sessions"],
                             SAMPLE["measurements_per_class"], SAMPLE["classes"][:1], batch=8,
                             position_rate_hz=SAMPLE["position_rate_hz"])
    assert path.read_bytes() == (DATA / path.name).read_bytes()
    assert path.with_suffix(".json").read_bytes() == (DATA / path.name).with_suffix(
        ".json").read_bytes()


@pytest.mark.slow
def test_demo_segments_fits_and_compares_with_truth(tmp_path):
    result = CliRunner().invoke(app, ["demo", "--data", str(DATA), "--out", str(tmp_path)])
    assert result.exit_code == 0, result.output
    assert "segmented 16 motions" in result.output
    assert "[[Variables]]" in result.output and "truth/fit (index_x" in result.output
    assert (tmp_path / "fits.csv").exists()
    assert "accuracy on the sample data: " in result.output
