"""Facts about the machine the process runs on. Importing this module never imports JAX."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["available_cores", "jax_cache_dir"]


def available_cores() -> int:
    """The CPU cores this process may run on."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def jax_cache_dir() -> Path | None:
    """Where JAX keeps compiled programs between processes, or None (cache off).

    ``$FRICTIONFIT_JAX_CACHE``: a folder, or ``0``/``off`` to turn the cache off;
    default ``$XDG_CACHE_HOME/frictionfit/jax`` (``~/.cache/frictionfit/jax``).
    """
    env = os.environ.get("FRICTIONFIT_JAX_CACHE", "").strip()
    if env.lower() in ("0", "off", "no", "false"):
        return None
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "frictionfit" / "jax"
