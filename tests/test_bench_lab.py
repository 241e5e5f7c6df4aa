"""The lab benchmark: whole fits of lab recordings scored without a truth."""

from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from frictionfit.bench import lab
from frictionfit.bench.report import merge, to_markdown
from frictionfit.cli import app


def test_sessions_agree_when_the_classes_keep_their_order():
    rows = []
    for session, shift in ((1, 0.0), (2, 0.3), (3, -0.1)):  # a day's offset does not matter
        for c, level in enumerate((0.2, 0.5, 0.9, 1.4)):
            rows.append({"channel": "index_x", "session": session, "label": f"c{c}",
                         "k": level + shift, "f_kin": level * 2 + shift})
            rows.append({"channel": "thumb_x", "session": session, "label": f"c{c}",
                         "k": level * (1 if session == 1 else -1), "f_kin": level})
    out = lab._agreement(pd.DataFrame(rows))
    assert out["index_x"]["agreement_k"] == pytest.approx(1.0)
    assert out["index_x"]["agreement_f_kin"] == pytest.approx(1.0)
    # sessions 1-2 and 1-3 reversed (-1), 2-3 the same (+1): mean -1/3
    assert out["thumb_x"]["agreement_k"] == pytest.approx(-1 / 3)


def test_spread_over_motions_is_sd_over_median_per_item():
    values = pd.DataFrame({"k": [10.0, 10.0, 10.0, 10.0, 12.0, 8.0],
                           "f_kin": [1.0, 1.1, 1.2, 1.0, 1.0, 1.0]})
    motions = SimpleNamespace(values=values)
    out = lab._spread(motions, np.array([0, 0, 0, 1, 1, 1]))
    assert out["k"]["median"] == pytest.approx(np.median([0.0, 2.0 / 10.0]))
    assert out["k"]["within_goal"] == 0.5 and out["k"]["items"] == 2
    assert out["f_kin"]["median"] == pytest.approx(np.median([0.1 / 1.1, 0.0]))


def test_cli_lab_needs_a_folder_and_only_lab_takes_one(tmp_path):
    run = CliRunner().invoke(app, ["bench", "lab", "--out", str(tmp_path)])
    assert run.exit_code != 0 and "lab needs a folder of recordings" in run.output
    run = CliRunner().invoke(app, ["bench", "fit", "--out", str(tmp_path), "--dataset",
                                   str(tmp_path)])
    assert run.exit_code != 0 and "only lab takes one" in run.output


def test_lab_bench_on_the_lab_recordings(shared):
    stage = lab.run(shared / "datasets" / "rubbing-lab", quick=True)
    s = stage["summary"]
    assert list(s["lab"]) == list(lab.FITS) and len(stage["points"]) == len(lab.FITS)
    assert s["lab_channels"] == 2 * 21  # every 20th of 420 recordings, thumb_x and index_x
    assert s["lab"]["relaxation2, wear 0"]["laws"] == {"relaxation2": 42}
    for scores in s["lab"].values():
        assert 0.8 <= scores["converged_key_unflagged_rate"] <= scores["converged_rate"] <= 1
        assert sum(scores["laws"].values()) == s["lab_channels"]
        for p in lab.DETERMINED:
            spread = scores["motion_spread_by_param"][p]
            assert 0.0 < spread["median"] < 0.1 and spread["items"] == s["lab_channels"]
        for ch in ("thumb_x", "index_x"):
            ranks = scores["by_channel"][ch]
            assert ranks["materials"] >= 3
            assert -1.0 <= ranks["rank_k_vs_onset_rate"] <= 1.0
            assert np.isfinite(ranks["agreement_k"])
    assert s["lab_converged_rate"] == s["lab"]["auto"]["converged_rate"]
    text = to_markdown(merge([stage]))
    assert "## lab, auto: " in text and "## lab, relaxation2, wear 0: " in text
    assert "## lab, auto, rig per session: " in text
    assert "sessions' agreement, log k (Pearson)" in text
