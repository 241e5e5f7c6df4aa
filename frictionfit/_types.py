"""Small shared types. Importing this module never imports JAX."""

from __future__ import annotations

from os import PathLike
from typing import Literal, Union

import numpy as np
from jaxtyping import Float

PathType = Union[str, "PathLike[str]"]
OnError = Literal["raise", "flag"]

Samples = Float[np.ndarray, "time channel"]
Times = Float[np.ndarray, " time"]

__all__ = ["OnError", "PathType", "Samples", "Times"]
