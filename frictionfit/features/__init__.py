"""Feature sets: scikit-learn transformers from a list of recordings to a named ``X``.

Names used on the command line map to transformer classes here; a comma list
(``"physical,spectral"``) concatenates them.
"""

from __future__ import annotations

import importlib

from sklearn.pipeline import FeatureUnion

__all__ = ["FEATURE_SETS", "make_features"]

#: Feature-set name -> "module:Class" of its transformer.
FEATURE_SETS = {
    "physical": "frictionfit.features.physical:PhysicalFeatures",
    "fitted": "frictionfit.features.physical:FittedFeatures",
    "sliding": "frictionfit.features.sliding:SlidingPhysicalFeatures",
    "handcrafted": "frictionfit.features.handcrafted:HandcraftedFeatures",
    "fftbins": "frictionfit.features.fftbins:FFTBinFeatures",
    "spectral": "frictionfit.features.spectral:SpectralPCAFeatures",
    "raw": "frictionfit.features.raw:RawSignalFeatures",
    "gesture": "frictionfit.features.wavelet:GestureFeatures",
    "touch": "frictionfit.features.touch:TouchPhysicalFeatures",
    "shortcut": "frictionfit.features.shortcut:ShortcutFeatures",
}


def feature_class(name: str) -> type:
    if name not in FEATURE_SETS:
        raise ValueError(f"unknown feature set {name!r}; choose from {sorted(FEATURE_SETS)}")
    module, _, cls = FEATURE_SETS[name].partition(":")
    return getattr(importlib.import_module(module), cls)


def make_features(names: str, **params):
    """A transformer for ``"a,b,..."``: one feature set, or a FeatureUnion of several.

    ``params`` are passed to every feature set whose constructor takes them.
    """
    parts = [n.strip() for n in names.split(",") if n.strip()]
    if not parts:
        raise ValueError("no feature set named")
    built = []
    for name in parts:
        cls = feature_class(name)
        accepted = cls._get_param_names() if hasattr(cls, "_get_param_names") else []
        built.append((name, cls(**{k: v for k, v in params.items() if k in accepted})))
    return built[0][1] if len(built) == 1 else FeatureUnion(built)
