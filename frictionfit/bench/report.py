"""The benchmark report: merge stage results, write ``bench.json``, ``bench.md`` and the plot.

A *stage dict* is what each ``frictionfit.bench.<stage>.run`` returns::

    {"stage": "fit", "summary": {...}, "machine": {...},
     "points": [{"config": str, "seconds_per_trial": float, "error": float,
                 "error_name": str, ...}, ...]}

Errors are smaller-is-better, except where ``error_name`` is exactly "accuracy" or
a point says ``"higher_is_better": true`` ("1 - accuracy" is an ordinary error).
The report marks, per stage, the Pareto front of time per trial against error:
the configurations that no other configuration beats on both at once.
"""

from __future__ import annotations

import copy
import json
import math
import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from frictionfit.bench.timing import machine_info

__all__ = ["merge", "pareto_front", "to_markdown", "write_report"]


def _num(value) -> float:
    """A float; None (a non-finite number after a JSON round trip) is NaN."""
    return np.nan if value is None else float(value)


def _higher_is_better(point: Mapping) -> bool:
    name = str(point.get("error_name", "")).strip().lower()
    return bool(point.get("higher_is_better", name == "accuracy"))


def pareto_front(points: Sequence[Mapping]) -> list[bool]:
    """Per point, True when no other point is at least as fast and as good, and better in one.

    Points with a non-finite time or error are never on the front.

    Examples
    --------
    >>> pareto_front([{"seconds_per_trial": 1.0, "error": 0.1},
    ...               {"seconds_per_trial": 2.0, "error": 0.2},
    ...               {"seconds_per_trial": 3.0, "error": 0.05}])
    [True, False, True]
    """
    xy = np.array([[_num(p["seconds_per_trial"]),
                    -_num(p["error"]) if _higher_is_better(p) else _num(p["error"])]
                   for p in points], dtype=np.float64).reshape(-1, 2)
    finite = np.all(np.isfinite(xy), axis=1)
    front = []
    for i, row in enumerate(xy):
        dominated = np.all(xy <= row, axis=1) & np.any(xy < row, axis=1) & finite
        front.append(bool(finite[i] and not dominated.any()))
    return front


def merge(stages: Sequence[Mapping], *, scaling: Mapping | None = None,
          dask: Mapping | None = None, hard_cases: Mapping | None = None,
          command: str = "") -> dict:
    """One benchmark document from stage dicts and the optional scaling/Dask/hard-case parts.

    The top-level ``summary`` holds every stage summary's keys (a key two stages
    share with different values is kept under ``<stage>_<key>`` for the later
    one), plus ``scaling`` (a list of ``{"trials": n, "seconds": s}``) and
    ``dask_speedup_2_workers`` when those parts are given. A stage that failed
    is a dict with ``"error"`` and is listed, not merged.
    """
    stages = copy.deepcopy(list(stages))
    summary: dict = {}
    for stage in stages:
        for key, value in stage.get("summary", {}).items():
            if key in summary and summary[key] != value:
                key = f"{stage['stage']}_{key}"
            summary[key] = value
    if scaling is not None:
        summary["scaling"] = [{"trials": p["trials"], "seconds": p["seconds"]}
                              for p in scaling["points"]]
        summary["scaling_exponent"] = scaling["summary"]["scaling_exponent"]
    if dask is not None:
        summary["dask_speedup_2_workers"] = dask["summary"]["dask_speedup_2_workers"]
    if hard_cases is not None:
        summary.update(hard_cases["summary"])
    for stage in stages:
        for point, on_front in zip(stage.get("points", []),
                                   pareto_front(stage.get("points", [])), strict=True):
            point["pareto"] = on_front
    return {"summary": summary, "command": command, "machine": machine_info(),
            "stages": {s["stage"]: dict(s) for s in stages},
            **{k: v for k, v in (("scaling", scaling), ("dask", dask),
                                 ("hard_cases", hard_cases)) if v is not None}}


def _clean(obj):
    """JSON-safe copy: NumPy scalars/arrays to Python, non-finite floats to None."""
    if isinstance(obj, Mapping):
        return {str(k): _clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, np.ndarray)):
        return [_clean(v) for v in obj]
    if isinstance(obj, np.generic):
        obj = obj.item()
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def _fmt(value) -> str:
    if isinstance(value, bool) or value is None:
        return str(value)
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return f"{value:.4g}"
    return str(value).replace("|", "\\|")  # a bare pipe would split the table cell


def _table(header: Sequence[str], rows: Sequence[Sequence]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(_fmt(v) for v in row) + " |" for row in rows]
    return lines + [""]


def to_markdown(bench: Mapping) -> str:
    """The report as Markdown: one table per stage, then scaling, Dask and hard cases."""
    lines = ["# frictionfit benchmark", ""]
    if bench.get("command"):
        lines += [f"Command: `{bench['command']}`", ""]
    machine = bench.get("machine", {})
    versions = machine.get("versions", {})
    lines += [f"Machine: {machine.get('processor')} x{machine.get('cpu_count')}, "
              f"Python {machine.get('python')}, jax {versions.get('jax')}, "
              f"optimistix {versions.get('optimistix')}, dask {versions.get('dask')}.", ""]
    for name, stage in bench.get("stages", {}).items():
        lines += [f"## {name}", ""]
        if "error" in stage:
            lines += [f"Stage failed: {stage['error']}", ""]
            continue
        points = sorted(stage.get("points", []),
                        key=lambda p: np.nan_to_num(_num(p["seconds_per_trial"]), nan=np.inf))
        lines += _table(["configuration", "s / trial", "error", "value", "Pareto"],
                        [[p["config"], p["seconds_per_trial"], p["error_name"], p["error"],
                          "**yes**" if p.get("pareto") else ""] for p in points])
    for name, stage in bench.get("stages", {}).items():
        for key, what in MEASUREMENT_BLOCKS.items():
            meas = stage.get("summary", {}).get(key)
            if meas:
                lines += _measurements(f"{name}: {what}", meas)
        if stage.get("summary", {}).get("rigs"):
            lines += _rigs(f"{name}: the material on simulated rigs", stage["summary"]["rigs"])
    for name, stage in bench.get("stages", {}).items():
        if stage.get("summary", {}).get("whole_coverage_by_param"):
            lines += _whole_coverage(f"{name}: coverage of whole-measurement posteriors",
                                     stage["summary"])
    for name, stage in bench.get("stages", {}).items():
        for model, scores in stage.get("summary", {}).get("lab", {}).items():
            lines += _lab(f"{name}, {model}: {stage.get('dataset', 'lab recordings')}", scores)
    lines += ["## Summary", ""]
    lines += _table(["key", "value"], [[k, v] for k, v in bench.get("summary", {}).items()
                                       if not isinstance(v, (list, dict))])
    if "scaling" in bench:
        lines += ["## Scaling", ""]
        pts = bench["scaling"]["points"]
        lines += _table(["trials", "seconds", "s / trial", "peak RSS so far (MB)"],
                        [[p["trials"], p["seconds"], p["seconds"] / p["trials"],
                          p["max_rss_mb"]] for p in pts])
        lines += _table(["trial length (s)", "trials", "s / trial"],
                        [[p["duration_s"], p["trials"], p["seconds_per_trial"]]
                         for p in bench["scaling"].get("lengths", [])])
    if "dask" in bench:
        d = bench["dask"]["summary"]
        lines += ["## Dask", "", f"{d['trials']} trials: one process {d['local_s']:.3g} s, "
                  f"Dask cluster of {d['workers']} workers {d['dask_s']:.3g} s: speed-up "
                  f"{d['dask_speedup_2_workers']:.3g}x.", ""]
    if "hard_cases" in bench:
        lines += ["## Hard cases", ""]
        lines += _table(["case", "trial", "fit status", "fit", "Laplace", "passed", "detail"],
                        [[r["case"], r["trial"], r["status"], r["outcome"], r["laplace"],
                          "yes" if r["passed"] and r["laplace_passed"] else "**NO**",
                          "; ".join(d for d in (r["detail"], r["laplace_detail"]) if d)]
                         for r in bench["hard_cases"]["cases"]])
    return "\n".join(lines)


#: Summary keys of the whole-measurement blocks -> their headings.
MEASUREMENT_BLOCKS = {"measurements": "whole measurements",
                      "measurements_motor_reads": "whole measurements, motor read at 50 Hz"}


#: The material's parameters whose recovery is compared between simulated rigs.
RIG_SCORED = ("k", "f_kin", "relax_frac", "tau")


def _rigs(heading: str, rigs: Mapping) -> list[str]:
    """One row per simulated rig: median |relative error| of the material's parameters."""
    lines = [f"## {heading}", "", "Whole measurements (index_x) made on each rig; median "
             "|relative error| against the material's truth (converged fits).", ""]
    return lines + _table(
        ["rig", "measurements", "converged", *RIG_SCORED],
        [[rig, m["n_recordings"], m["converged_rate"],
          *(m["median_rel_error_by_param"].get(p) for p in RIG_SCORED)]
         for rig, m in rigs.items()])


def _measurements(heading: str, meas: Mapping) -> list[str]:
    """A whole-measurement section: recovery per parameter, then the peers."""
    lines = [f"## {heading}", "",
             f"{meas['n_recordings']} simulated measurements, {meas['channel']}: "
             f"{meas['recordings_per_s']:.3g} recordings/s (compile "
             f"{meas['compile_s']:.3g} s), converged {meas['converged_rate']:.3g}, "
             f"converged with no law parameter flagged "
             f"{meas['converged_unflagged_rate']:.3g}.", ""]
    lines += _table(["parameter", "median |rel. error|", "median signed error",
                     "flagged", "truth within +-1 stderr", "within +-1.96 stderr"],
                    [[k, v, meas["median_signed_error_by_param"][k],
                      meas["flagged_rate_by_param"].get(k),
                      meas["stderr_coverage_by_param"].get(k),
                      meas.get("stderr_coverage95_by_param", {}).get(k)]
                     for k, v in meas["median_rel_error_by_param"].items()])
    if meas.get("peers"):
        tie = next(iter(meas["peers"].values()))["cost_tie"]
        lines += ["One law (relaxation2), one fit from the same start; ours batched over the "
                  "peer's recordings. Cost difference: (ours - peer) / peer, median; the "
                  f"peer's optimum higher / lower than ours by more than {tie:.1%}: on how "
                  "many recordings.", ""]
        lines += _table(["peer", "recordings", "s / recording", "ours s / recording",
                         "ours faster by", "cost difference", "peer higher", "peer lower"],
                        [[peer, p["n_recordings"], p["s_per_recording"],
                          p["ours_s_per_recording"], p["speedup"], p["median_cost_rel_diff"],
                          p["n_peer_cost_higher"], p["n_peer_cost_lower"]]
                         for peer, p in meas["peers"].items()])
    return lines


def _whole_coverage(heading: str, s: Mapping) -> list[str]:
    """One row per key law parameter: the share of whole-measurement rows whose truth lies
    in the 68 % and 95 % posterior intervals, Laplace and emcee, with the rows counted."""
    cov, n = s["whole_coverage_by_param"], s.get("whole_coverage_n_by_param", {})
    lines = [f"## {heading}", "",
             f"{s['whole_n']} simulated measurements ({s['whole_channel']}), fitted whole with "
             f"the defaults (laws {s.get('whole_laws')}); truth within the posterior's "
             f"68 % (p16-p84) and 95 % (p2.5-p97.5) intervals. Laplace over the rows with a "
             f"finite posterior ({s['whole_laplace_s_per_recording']:.3g} s per recording); "
             f"emcee on the first {s['whole_n_emcee']}, step cap {s['whole_emcee_max_steps']}, "
             f"over {s['whole_emcee_coverage_over']}: converged "
             f"{_fmt(s['whole_emcee_converged_rate'])}, "
             f"{_fmt(s['whole_emcee_s_per_recording'])} s per recording.", ""]

    def pair(method: str, p: str) -> list:
        return list(cov.get(method, {}).get(p) or [None, None])

    params = list(cov.get("laplace", {}) or cov.get("emcee", {}))
    return lines + _table(
        ["parameter", "Laplace 68 %", "Laplace 95 %", "rows", "emcee 68 %", "emcee 95 %",
         "rows", "emcee, all rows 68 %", "95 %"],
        [[p, *pair("laplace", p), n.get("laplace", {}).get(p), *pair("emcee", p),
          n.get("emcee", {}).get(p), *pair("emcee_all_rows", p)] for p in params])


def _lab(heading: str, lab: Mapping) -> list[str]:
    """A lab section: fits, spread over motions, then each channel's agreement and ranks."""
    lines = [f"## {heading}", "",
             f"{lab['channels']} channels in {lab['fit_s']:.3g} s after compilation "
             f"(the first, compiling, {lab['compile_s']:.3g} s longer); laws "
             + ", ".join(f"{law} {n}" for law, n in lab["laws"].items())
             + f"; converged {lab['converged_rate']:.3g}, with "
             + " and ".join(lab["flagged_by_param"]) + " unflagged "
             f"{lab['converged_key_unflagged_rate']:.3g} (flagged: "
             + ", ".join(f"{p} {n}" for p, n in lab["flagged_by_param"].items()) + ").", ""]
    lines += _table(["parameter", "spread over motions (sd / median), median",
                     "channels within 5 %"],
                    [[p, s["median"], s["within_goal"]]
                     for p, s in lab["motion_spread_by_param"].items()])
    channels = lab["by_channel"]
    keys = list(next(iter(channels.values()), {}))
    lines += _table(["channel", *(_LAB_COLUMNS.get(k, k) for k in keys)],
                    [[ch, *(v.get(k) for k in keys)] for ch, v in channels.items()])
    return lines


#: Column headings of the lab section's per-channel table.
_LAB_COLUMNS = {"agreement_k": "sessions' agreement, log k (Pearson)",
                "agreement_f_kin": "sessions' agreement, log f_kin (Pearson)",
                "rank_k_vs_onset_rate": "k against measured onset rate (Spearman)",
                "rank_f_kin_vs_held": "f_kin against measured held level (Spearman)",
                "materials": "one-layer materials"}


def plot_speed_vs_error(bench: Mapping, path: Path) -> None:
    """Time per trial (log x) against error, one panel per stage, Pareto front marked."""
    from frictionfit._optional import pyplot

    plt = pyplot("speed_vs_error.png")

    stages = [(n, s) for n, s in bench.get("stages", {}).items() if s.get("points")]
    fig, axes = plt.subplots(1, max(len(stages), 1), figsize=(5.5 * max(len(stages), 1), 4.2),
                             squeeze=False)
    for ax, (name, stage) in zip(axes[0], stages, strict=False):
        pts = stage["points"]
        x = np.array([_num(p["seconds_per_trial"]) for p in pts])
        y = np.array([_num(p["error"]) for p in pts])
        front = np.array(pareto_front(pts))
        ax.scatter(x[~front], y[~front], c="0.6", s=25, label="configuration")
        order = np.argsort(x[front])
        ax.plot(x[front][order], y[front][order], "o-", c="C3", ms=6, label="Pareto front")
        for xi, yi, p in zip(x, y, pts, strict=True):
            ax.annotate(p["config"], (xi, yi), fontsize=6, xytext=(3, 3),
                        textcoords="offset points")
        ax.set_xscale("log")
        ax.set_xlabel("time per trial (s)")
        ax.set_ylabel(textwrap.fill(str(pts[0]["error_name"]), 38), fontsize=8)
        ax.set_title(name)
        ax.legend(fontsize=7)
    if not stages:
        axes[0, 0].text(0.5, 0.5, "no stage with points", ha="center")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def write_report(bench: Mapping, out: Path) -> dict[str, Path]:
    """Write ``bench.json``, ``bench.md`` and ``speed_vs_error.png`` into ``out`` (created);
    without matplotlib (the ``plots`` extra) the PNG is left out of the returned paths."""
    from frictionfit._optional import MissingExtraError

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"json": out / "bench.json", "markdown": out / "bench.md",
             "plot": out / "speed_vs_error.png"}
    paths["json"].write_text(json.dumps(_clean(bench), indent=2, allow_nan=False) + "\n")
    paths["markdown"].write_text(to_markdown(bench) + "\n")
    try:
        plot_speed_vs_error(bench, paths["plot"])
    except MissingExtraError:
        del paths["plot"]
    return paths


def frame_markdown(frame) -> str:
    """A DataFrame as a markdown table (numbers to 4 significant digits)."""
    return "\n".join(_table(list(map(str, frame.columns)),
                            [list(row) for row in frame.itertuples(index=False)]))


def record_results(path: Path, command: str, markdown: str, today: str | None = None) -> Path:
    """Add a dated section (the command, the machine, ``markdown``) to a results file such as
    ``docs/results.md``, above the sections already there (created when missing)."""
    import datetime

    path = Path(path)
    machine = machine_info()
    day = today or datetime.date.today().isoformat()
    section = (f"## {day}: `{command}`\n\nMachine: {machine['cpu_count']} cores, "
               f"{machine['platform']}, Python {machine['python']}.\n\n{markdown.strip()}\n\n")
    text = path.read_text() if path.exists() else "# Measured results\n\n"
    at = text.find("\n## ")
    text = text.rstrip() + "\n\n" + section if at < 0 else text[:at + 1] + section + text[at + 1:]
    path.write_text(text)
    return path
