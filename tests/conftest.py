"""Test configuration: float64 and strict promotion for JAX, seeds, the shared-data fixture."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

os.environ.setdefault("MPLBACKEND", "Agg")

REPO_ROOT = Path(__file__).resolve().parents[1]


def pytest_configure(config):
    try:
        import jax
    except ImportError:  # pragma: no cover - jax is a hard dependency
        return
    jax.config.update("jax_enable_x64", True)
    jax.config.update("jax_numpy_rank_promotion", "raise")


@pytest.fixture(scope="module")
def feature_cache(tmp_path_factory):
    """An empty feature cache (``FRICTIONFIT_CACHE``) for one test module: no stale rows."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("FRICTIONFIT_CACHE", str(tmp_path_factory.mktemp("cache")))
        yield


@pytest.fixture
def rng():
    return np.random.default_rng(20261122)


@pytest.fixture(scope="session")
def shared():
    """The team's ``../shared`` folder; tests that need it skip with a reason when absent."""
    from frictionfit.datasets import shared_dir

    path = shared_dir()
    if path is None:
        pytest.skip(f"../shared not found beside the repo ({REPO_ROOT.parent / 'shared'})")
    return path
