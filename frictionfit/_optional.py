"""Optional dependencies: imported where they are used, with an error naming the extra.

The core install (``pip install frictionfit``) reads, segments, fits, featurises and
classifies recordings. What only some users need sits behind extras:

- ``acquisition``: pyserial (OptoForce sensors and the Dynamixel gripper);
- ``distributed``: Dask's ``distributed`` (fits on a cluster);
- ``store``: h5py (emcee chains on disk) and pyarrow (Parquet tables);
- ``plots``: matplotlib, corner and arviz (PNGs, corner plots, InferenceData).

:func:`require` imports a module of an extra or raises :class:`MissingExtraError`
naming the ``pip install`` line; :func:`lazy_module` defers that import to the first
attribute access, for modules that name the dependency at their top.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from frictionfit.errors import FrictionfitError

__all__ = ["EXTRAS", "MissingExtraError", "lazy_module", "pyplot", "require"]

#: The distribution that provides each optional top-level module, and its extra.
EXTRAS: dict[str, tuple[str, str]] = {
    "serial": ("pyserial", "acquisition"),
    "distributed": ("dask[distributed]", "distributed"),
    "h5py": ("h5py", "store"),
    "pyarrow": ("pyarrow", "store"),
    "matplotlib": ("matplotlib", "plots"),
    "corner": ("corner", "plots"),
    "arviz": ("arviz", "plots"),
}


class MissingExtraError(FrictionfitError, ImportError):
    """An optional dependency is not installed; the message names the extra that brings it.

    Attributes
    ----------
    extra : str
        The extra to install (``pip install "frictionfit[<extra>]"``).
    """

    def __init__(self, module: str, purpose: str):
        package, self.extra = EXTRAS[module.split(".")[0]]
        super().__init__(f"{purpose} needs {package}, which is not installed: "
                         f'pip install "frictionfit[{self.extra}]"', name=module)


def require(module: str, purpose: str) -> ModuleType:
    """Import ``module`` (a module of one of :data:`EXTRAS`).

    Parameters
    ----------
    module : str
        Dotted module name, e.g. ``"matplotlib.pyplot"``.
    purpose : str
        What needs it, for the message (e.g. ``"frictionfit plot"``).

    Raises
    ------
    MissingExtraError
        When the module's distribution is not installed.
    """
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as exc:
        if exc.name == module.split(".")[0]:  # the distribution itself, not a part of it
            raise MissingExtraError(module, purpose) from exc
        raise


def pyplot(purpose: str) -> ModuleType:
    """``matplotlib.pyplot`` on the non-interactive Agg backend (files only)."""
    matplotlib = require("matplotlib", purpose)
    matplotlib.use("Agg")
    return require("matplotlib.pyplot", purpose)


class _LazyModule(ModuleType):
    """A stand-in for a module of an extra, imported on first attribute access."""

    def __init__(self, module: str, purpose: str):
        super().__init__(module)
        self._purpose = purpose

    def __getattr__(self, attr: str):
        if attr.startswith("__"):
            raise AttributeError(attr)
        return getattr(require(self.__name__, self._purpose), attr)


def lazy_module(module: str, purpose: str) -> ModuleType:
    """A stand-in for ``module`` that imports it (or raises :class:`MissingExtraError`)
    when one of its attributes is first used."""
    return _LazyModule(module, purpose)
