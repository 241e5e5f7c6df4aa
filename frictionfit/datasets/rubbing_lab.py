"""Rubbing-experiment folders in the interchange format (ours and the lab's)."""

from __future__ import annotations

import warnings

from frictionfit._types import PathType
from frictionfit.errors import DatasetError
from frictionfit.recording import DatasetWarning, Recording, read_dataset
from frictionfit.segmentation import segment


def load(path: PathType, strict: bool = False) -> list[Recording]:
    """Read a folder of rubbing measurements: damaged ones are kept with their problems
    flagged; unusable ones are skipped with a warning (``strict``: raise). A recording that
    ends early is kept if it holds a complete motion after the preparatory one."""
    kept = []
    for rec in read_dataset(path, on_error="flag", strict=strict):
        if any(p.kind == "ends_early" for p in rec.problems) and not segment(rec):
            why = (f"skipped {rec.name}: it ends at t={rec.t[-1]:.6g} s, before a complete "
                   "motion after the preparatory one")
            if strict:
                raise DatasetError(why)
            warnings.warn(why, DatasetWarning, stacklevel=2)
            continue
        kept.append(rec)
    if not kept:
        raise DatasetError(f"{path}: none of its recordings holds a complete motion")
    return kept
