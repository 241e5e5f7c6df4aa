"""Rubbing-experiment folders in the interchange format (ours and the lab's)."""

from __future__ import annotations

from frictionfit._types import PathType
from frictionfit.recording import Recording, read_dataset


def load(path: PathType, strict: bool = False) -> list[Recording]:
    """Read a folder of rubbing measurements: damaged ones are kept with their problems
    flagged; unusable ones are skipped with a warning (``strict``: raise)."""
    return read_dataset(path, on_error="flag", strict=strict)
