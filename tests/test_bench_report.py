"""The benchmark report: merging stage dicts, the Pareto front, the files, and the CLI."""

import json
import sys
import types

import pytest
from typer.testing import CliRunner

from frictionfit.bench.report import merge, pareto_front, to_markdown, write_report
from frictionfit.cli import app


def _stage(name, points, **summary):
    return {"stage": name, "summary": summary, "machine": {},
            "points": [{"config": c, "seconds_per_trial": s, "error": e, "error_name": n}
                       for c, s, e, n in points]}


FIT = _stage("fit", [("lm", 0.01, 0.02, "median rel. error"),
                     ("scipy-numpy", 0.5, 0.02, "median rel. error"),
                     ("dogleg", 0.02, 0.01, "median rel. error"),
                     ("float32", 0.005, float("nan"), "median rel. error")],
             trials_per_s=100.0, compile_s=3.0)
UNC = _stage("uncertainty", [("laplace", 0.001, 0.1, "interval error"),
                             ("emcee-32x500", 0.8, 0.03, "interval error")],
             emcee_s_per_trial=0.8, compile_s=5.0)
CLS = _stage("classify", [("physical", 0.002, 0.9, "accuracy"),
                          ("spectral", 0.001, 0.7, "accuracy"),
                          ("raw", 0.003, 0.8, "accuracy")], accuracy=0.9)
SCALING = {"stage": "scaling", "summary": {"scaling_exponent": 0.93},
           "points": [{"trials": n, "seconds": n * 0.01, "max_rss_mb": 500.0}
                      for n in (10, 100)],
           "lengths": [{"duration_s": 0.5, "trials": 8, "seconds_per_trial": 0.002}]}
HARD = {"stage": "hard_cases", "summary": {"hard_cases_total": 1, "hard_cases_fit_passed": 0},
        "cases": [{"case": "clipped", "trial": 0, "status": "converged",
                   "outcome": "confident_wrong", "passed": False, "detail": "f_kin=2 (truth 1)",
                   "laplace": "correct", "laplace_passed": True, "laplace_detail": ""}]}
DASK = {"stage": "dask", "summary": {"trials": 64, "local_s": 2.0, "dask_s": 1.25,
                                     "workers": 2, "dask_speedup_2_workers": 1.6}}


def test_pareto_front_smaller_is_better_and_nan_never_on_it():
    assert pareto_front(FIT["points"]) == [True, False, True, False]


def test_pareto_front_accuracy_is_higher_is_better():
    assert pareto_front(CLS["points"]) == [True, True, False]


def test_merge_summary_keeps_every_stage_key_and_adds_scaling_and_dask():
    bench = merge([FIT, UNC, CLS], scaling=SCALING, dask=DASK, command="frictionfit bench all")
    s = bench["summary"]
    assert s["trials_per_s"] == 100.0 and s["emcee_s_per_trial"] == 0.8
    assert s["compile_s"] == 3.0 and s["uncertainty_compile_s"] == 5.0  # clash kept apart
    assert s["scaling"] == [{"trials": 10, "seconds": 0.1}, {"trials": 100, "seconds": 1.0}]
    assert s["dask_speedup_2_workers"] == 1.6
    assert set(bench["machine"]["versions"]) >= {"jax", "optimistix", "dask"}
    assert [p["pareto"] for p in bench["stages"]["fit"]["points"]] == [True, False, True, False]
    assert "pareto" not in FIT["points"][0]  # the caller's dicts are not modified


def test_write_report_files(tmp_path):
    bench = merge([FIT, UNC, CLS], scaling=SCALING, dask=DASK, hard_cases=HARD,
                  command="frictionfit bench all")
    paths = write_report(bench, tmp_path / "out")
    data = json.loads(paths["json"].read_text())  # strict JSON: NaN became null
    assert data["stages"]["fit"]["points"][3]["error"] is None
    assert data["summary"]["dask_speedup_2_workers"] == 1.6
    md = paths["markdown"].read_text()
    assert "| dogleg | 0.02 | median rel. error | 0.01 | **yes** |" in md
    assert "speed-up 1.6x" in md and "`frictionfit bench all`" in md
    row = "| clipped | 0 | converged | confident_wrong | correct | **NO** | f_kin=2 (truth 1) |"
    assert row in md
    assert data["summary"]["hard_cases_fit_passed"] == 0
    assert paths["plot"].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_without_matplotlib_the_report_is_written_without_its_plot(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # the core install: no [plots]
    paths = write_report(merge([FIT]), tmp_path)
    assert sorted(paths) == ["json", "markdown"] and paths["markdown"].exists()
    assert not (tmp_path / "speed_vs_error.png").exists()


def test_failed_stage_is_listed_not_merged():
    failed = {"stage": "uncertainty", "error": "ImportError: nope", "summary": {}}
    bench = merge([FIT, failed])
    assert "Stage failed: ImportError: nope" in to_markdown(bench)
    assert "emcee_s_per_trial" not in bench["summary"]


def test_whole_measurements_list_recovery_and_both_peers():
    peer = {"n_recordings": 2, "s_per_recording": 9.0, "ours_s_per_recording": 0.25,
            "speedup": 36.0, "median_cost_rel_diff": 2e-6,
            "n_peer_cost_higher": 1, "n_peer_cost_lower": 0, "cost_tie": 1e-3}
    meas = {"n_recordings": 8, "channel": "index_x", "recordings_per_s": 3.0, "compile_s": 20.0,
            "converged_rate": 1.0, "converged_unflagged_rate": 0.875,
            "median_rel_error_by_param": {"k": 0.05}, "median_signed_error_by_param": {"k": 0.01},
            "flagged_rate_by_param": {"k": 0.0}, "stderr_coverage_by_param": {"k": 0.7},
            "peers": {"scipy-jax": dict(peer, n_recordings=4, speedup=7.0), "scipy-numpy": peer}}
    reads = dict(meas, median_rel_error_by_param={"k": 0.03}, peers={})
    fit = dict(FIT, summary=dict(FIT["summary"], measurements=meas,
                                 measurements_motor_reads=reads))
    md = to_markdown(merge([fit]))
    assert "| k | 0.05 | 0.01 | 0 | 0.7 |" in md
    with_reads = md.split("## fit: whole measurements, motor read at 50 Hz")[1]
    assert "| k | 0.03 | 0.01 | 0 | 0.7 |" in with_reads and "scipy" not in with_reads
    assert "| scipy-jax | 4 | 9 | 0.25 | 7 | 2e-06 | 1 | 0 |" in md
    assert "| scipy-numpy | 2 | 9 | 0.25 | 36 | 2e-06 | 1 | 0 |" in md
    assert "by more than 0.1%" in md


def test_cli_rejects_unknown_benchmark(tmp_path):
    result = CliRunner().invoke(app, ["bench", "speed", "--out", str(tmp_path)])
    assert result.exit_code == 2
    assert "unknown benchmark 'speed'" in result.output


def test_cli_bench_one_stage_writes_the_report(tmp_path, monkeypatch):
    fake = types.ModuleType("frictionfit.bench.fit")
    fake.run = lambda *, quick=False, seed=0: FIT
    monkeypatch.setitem(sys.modules, "frictionfit.bench.fit", fake)
    result = CliRunner().invoke(app, ["bench", "fit", "--out", str(tmp_path), "--quick"])
    assert result.exit_code == 0, result.output
    data = json.loads((tmp_path / "bench.json").read_text())
    assert data["summary"]["trials_per_s"] == 100.0
    assert data["command"] == f"frictionfit bench fit --out {tmp_path} --quick"
    assert (tmp_path / "speed_vs_error.png").exists()


def test_cli_failing_stage_exits_1_but_writes(tmp_path, monkeypatch):
    fake = types.ModuleType("frictionfit.bench.classify")

    def run(*, quick=False, seed=0):
        raise RuntimeError("no classifier")

    fake.run = run
    monkeypatch.setitem(sys.modules, "frictionfit.bench.classify", fake)
    result = CliRunner().invoke(app, ["bench", "classify", "--out", str(tmp_path)])
    assert result.exit_code == 1
    assert "stage classify failed: RuntimeError: no classifier" in result.output
    assert "Stage failed" in (tmp_path / "bench.md").read_text()


@pytest.mark.parametrize("bad", [float("inf"), float("-inf")])
def test_non_finite_summary_values_are_null(tmp_path, bad):
    bench = merge([_stage("fit", [("lm", 0.01, 0.1, "e")], trials_per_s=bad)])
    data = json.loads(write_report(bench, tmp_path)["json"].read_text())
    assert data["summary"]["trials_per_s"] is None


def test_report_renders_again_from_its_json(tmp_path):
    stage = _stage("uncertainty", [("laplace", 0.01, 1.0, "mean |q - ref|"),
                                   ("reference", float("nan"), 0.0, "itself")])
    data = json.loads(write_report(merge([stage]), tmp_path / "a")["json"].read_text())
    paths = write_report(data, tmp_path / "b")  # NaN came back as null
    assert r"| laplace | 0.01 | mean \|q - ref\| | 1 | **yes** |" in paths["markdown"].read_text()


def test_one_minus_accuracy_is_an_error_to_minimise():
    # Regression: "1 - accuracy" once matched "accuracy" and was maximised.
    points = [{"seconds_per_trial": 1.0, "error": 0.05, "error_name": "1 - accuracy"},
              {"seconds_per_trial": 1.0, "error": 0.30, "error_name": "1 - accuracy"}]
    assert pareto_front(points) == [True, False]


def test_record_results_adds_a_dated_section_above_the_older_ones(tmp_path):
    import pandas as pd

    from frictionfit.bench.report import frame_markdown, record_results

    path = tmp_path / "results.md"
    path.write_text("# Measured results\n\nIntro.\n\n## 2026-01-01\n\nOld.\n")
    table = frame_markdown(pd.DataFrame({"features": ["physical"], "accuracy": [0.94051]}))
    record_results(path, "frictionfit evaluate --all", table, today="2026-11-24")
    text = path.read_text()
    assert text.index("## 2026-11-24: `frictionfit evaluate --all`") < text.index("## 2026-01-01")
    assert "| physical | 0.9405 |" in text and "cores" in text and text.startswith("# Measured")


def test_the_material_on_simulated_rigs_is_one_row_per_rig():
    meas = {"n_recordings": 35, "converged_rate": 0.9,
            "median_rel_error_by_param": {"k": 0.3, "f_kin": 0.02, "relax_frac": 0.5,
                                          "tau": 0.25, "ramp": 0.01}}
    rigs = {"sim-a": meas, "sim-b": dict(meas, converged_rate=1.0)}
    md = to_markdown(merge([dict(FIT, summary=dict(FIT["summary"], rigs=rigs))]))
    table = md.split("## fit: the material on simulated rigs")[1]
    assert "| rig | measurements | converged | k | f_kin | relax_frac | tau |" in table
    assert "| sim-a | 35 | 0.9 | 0.3 | 0.02 | 0.5 | 0.25 |" in table
    assert "| sim-b | 35 | 1 | 0.3 | 0.02 | 0.5 | 0.25 |" in table


def test_whole_measurement_coverage_is_one_row_per_parameter():
    whole = {"whole_n": 70, "whole_n_emcee": 12, "whole_channel": "index_x",
             "whole_laws": {"measurement-rich": 70}, "whole_laplace_s_per_recording": 0.01,
             "whole_emcee_max_steps": 2000, "whole_emcee_coverage_over": "converged rows",
             "whole_emcee_converged_rate": 0.25, "whole_emcee_s_per_recording": 15.0,
             "whole_coverage_by_param": {"laplace": {"k": [0.7, 0.96], "tau": [0.5, 0.8]},
                                         "emcee": {"k": [0.5, 1.0]},
                                         "emcee_all_rows": {"k": [0.6, 0.9]}},
             "whole_coverage_n_by_param": {"laplace": {"k": 70, "tau": 69},
                                           "emcee": {"k": 3}}}
    md = to_markdown(merge([dict(UNC, summary=dict(UNC["summary"], **whole))]))
    table = md.split("## uncertainty: coverage of whole-measurement posteriors")[1]
    assert "converged 0.25, 15 s per recording" in table
    assert "| k | 0.7 | 0.96 | 70 | 0.5 | 1 | 3 | 0.6 | 0.9 |" in table
    assert "| tau | 0.5 | 0.8 | 69 | None | None | None | None | None |" in table
