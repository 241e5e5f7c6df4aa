"""Timing rules shared by every benchmark: alternate, repeat, take the median.

Ratios between configurations are only meaningful when both are measured in the
same run, interleaved (A B A B ...), so that a machine whose speed drifts hurts
both alike. Compile / warm-up time is measured once, apart.
"""

from __future__ import annotations

import os
import platform
import time
from collections.abc import Callable, Mapping
from importlib import metadata

import numpy as np

__all__ = ["alternate", "machine_info", "timed"]


def timed(fn: Callable[[], object]) -> tuple[float, object]:
    """Wall time (s) of one call of ``fn`` and its result."""
    start = time.perf_counter()
    out = fn()
    return time.perf_counter() - start, out


def alternate(
    configs: Mapping[str, Callable[[], object]], repeats: int = 3, warmup: bool = True
) -> dict[str, dict[str, object]]:
    """Run every configuration ``repeats`` times, interleaved; report median seconds.

    Returns ``{name: {"warmup_s": s | None, "times_s": [...], "median_s": s, "result": last}}``.
    The warm-up call (compile, caches) is timed separately and never counted.
    """
    out: dict[str, dict[str, object]] = {
        name: {"warmup_s": None, "times_s": [], "result": None} for name in configs
    }
    if warmup:
        for name, fn in configs.items():
            out[name]["warmup_s"], out[name]["result"] = timed(fn)
    for _ in range(repeats):
        for name, fn in configs.items():
            seconds, out[name]["result"] = timed(fn)
            out[name]["times_s"].append(seconds)
    for entry in out.values():
        entry["median_s"] = float(np.median(entry["times_s"]))
    return out


def machine_info() -> dict[str, object]:
    """Machine and library versions, for the benchmark's JSON."""
    versions = {}
    for pkg in ("frictionfit", "jax", "jaxlib", "optimistix", "lineax", "equinox", "numpy",
                "scipy", "scikit-learn", "emcee", "dask", "distributed"):
        try:
            versions[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            versions[pkg] = None
    return {
        "python": platform.python_version(),
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "versions": versions,
    }
