"""The simulated material library: 18 household materials x {1, 2} layers = 35 classes.

Each class has central values of the contact law's parameters as the index
finger's x axis sees them (unit gain), plus a viscous drag that the fitted
family does not model. One layer: the sensor rubber rubs on the material. Two
layers: the layers slide on each other, so friction and stiffness are lower,
the static peak smaller and relaxation slower. Some classes are deliberately
close (the two curtains; paper and banknote; PE bag and cling film; scarf and
cotton fabric).

Spreads: every measurement draws its parameters log-normally around the class
(and session) values with :data:`SPREAD` (relative sd); a session multiplies
the material state by one factor per class with :data:`SESSION_SPREAD`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

__all__ = ["CLASSES", "MATERIALS", "SESSION_SPREAD", "SPREAD", "Material", "draw_parameters",
           "material_for"]


@dataclass(frozen=True)
class Material:
    """Central contact-law parameters of one class, physical units.

    Attributes
    ----------
    slug : str
        Material name, e.g. ``"bath-mat"``.
    layers : int
        1 or 2.
    k : float
        Tangential stiffness, N/mm.
    f_kin : float
        Kinetic friction level, N.
    static_ratio : float
        Static excess as a fraction of ``f_kin``.
    slip_length : float
        Slip-weakening length, mm.
    relax_frac, relax_frac2 : float
        Relaxing fractions of the two Maxwell branches.
    tau, tau2 : float
        Relaxation times, s.
    damping : float
        Viscous bristle damping, N s/mm.
    drag : float
        Velocity-proportional sliding drag, N s/mm (not in the fitted family).
    """

    slug: str
    layers: int
    k: float
    f_kin: float
    static_ratio: float
    slip_length: float
    relax_frac: float
    tau: float
    relax_frac2: float
    tau2: float
    damping: float
    drag: float

    @property
    def label(self) -> str:
        return f"{self.slug}-{self.layers}"


# slug: k, f_kin, static_ratio, slip_length, relax_frac, tau, relax_frac2, tau2, damping, drag
_ONE_LAYER: dict[str, tuple[float, ...]] = {
    "place-mat": (12.0, 0.90, 0.35, 0.06, 0.30, 0.12, 0.20, 1.0, 3e-3, 0.010),
    "bath-mat": (8.0, 1.30, 0.20, 0.10, 0.40, 0.18, 0.25, 1.3, 5e-3, 0.015),
    "cushion": (10.0, 2.00, 0.15, 0.12, 0.45, 0.25, 0.30, 1.6, 8e-3, 0.020),
    "floor-mat": (25.0, 1.60, 0.60, 0.04, 0.20, 0.08, 0.15, 0.8, 2e-3, 0.012),
    "carpet": (15.0, 1.40, 0.30, 0.08, 0.35, 0.15, 0.20, 1.2, 4e-3, 0.015),
    "scarf": (9.0, 0.70, 0.25, 0.08, 0.35, 0.15, 0.20, 1.1, 3e-3, 0.008),
    "cotton-fabric": (10.0, 0.76, 0.28, 0.07, 0.32, 0.13, 0.20, 1.0, 3e-3, 0.009),
    "basket": (18.0, 1.10, 0.40, 0.05, 0.25, 0.10, 0.15, 0.9, 3e-3, 0.012),
    "pe-bag": (30.0, 0.50, 0.50, 0.03, 0.15, 0.07, 0.15, 0.7, 2e-3, 0.006),
    "pencil-case": (20.0, 0.90, 0.35, 0.05, 0.25, 0.10, 0.18, 0.9, 3e-3, 0.010),
    "paper": (35.0, 0.60, 0.45, 0.03, 0.15, 0.06, 0.12, 0.8, 2e-3, 0.006),
    "belt": (22.0, 1.00, 0.40, 0.05, 0.25, 0.10, 0.15, 1.0, 3e-3, 0.010),
    "saran-wrap": (28.0, 0.55, 0.55, 0.03, 0.18, 0.07, 0.15, 0.7, 2e-3, 0.006),
    "laundry-net": (14.0, 0.60, 0.30, 0.06, 0.30, 0.12, 0.20, 0.9, 3e-3, 0.008),
    "curtain-rose": (10.0, 0.75, 0.30, 0.07, 0.30, 0.13, 0.20, 1.0, 3e-3, 0.008),
    "curtain-white": (10.5, 0.72, 0.30, 0.07, 0.30, 0.13, 0.20, 1.0, 3e-3, 0.008),
    "banknote": (33.0, 0.65, 0.45, 0.03, 0.16, 0.065, 0.12, 0.8, 2e-3, 0.006),
    "aluminium-foil": (40.0, 0.90, 0.50, 0.02, 0.10, 0.05, 0.10, 0.6, 1.5e-3, 0.008),
}

#: Two layers relative to one: factors on k, f_kin, static_ratio and tau; added relax_frac.
_TWO_LAYERS = {"k": 0.7, "f_kin": 0.65, "static_ratio": 0.6, "tau": 1.4, "relax_frac": 0.05}

#: Relative sd (log-normal) of a measurement's parameters around the class value.
SPREAD = {"k": 0.06, "f_kin": 0.06, "static_ratio": 0.08, "slip_length": 0.10,
          "relax_frac": 0.06, "tau": 0.10, "relax_frac2": 0.08, "tau2": 0.10,
          "damping": 0.10, "drag": 0.10}
#: Relative sd of the per-session, per-class material-state factor (wear, humidity).
SESSION_SPREAD = {"k": 0.05, "f_kin": 0.04, "tau": 0.05}


def _build() -> dict[str, Material]:
    out = {}
    for slug, values in _ONE_LAYER.items():
        one = Material(slug, 1, *values)
        out[one.label] = one
        if slug == "cushion":  # too thick to fold: one layer only
            continue
        two = replace(
            one, layers=2, k=one.k * _TWO_LAYERS["k"], f_kin=one.f_kin * _TWO_LAYERS["f_kin"],
            static_ratio=one.static_ratio * _TWO_LAYERS["static_ratio"],
            tau=one.tau * _TWO_LAYERS["tau"], relax_frac=one.relax_frac + _TWO_LAYERS["relax_frac"],
        )
        out[two.label] = two
    return out


#: label -> Material, 35 classes in library order (1 then 2 layers per material).
MATERIALS: dict[str, Material] = _build()
#: The 35 class labels, e.g. ``"paper-2"``.
CLASSES: tuple[str, ...] = tuple(MATERIALS)


def material_for(label: str) -> Material:
    """The library entry of a class label (``"<slug>-<layers>"``)."""
    try:
        return MATERIALS[label]
    except KeyError:
        raise ValueError(f"unknown class {label!r}; the library has {len(CLASSES)} classes, "
                         f"e.g. {list(CLASSES[:3])}") from None


def draw_parameters(material: Material, rng: np.random.Generator,
                    session_factor: dict[str, float]) -> dict[str, float]:
    """One measurement's law parameters (physical units) around the class and session values."""
    values = {}
    for name, sd in SPREAD.items():
        centre = getattr(material, name) * session_factor.get(name, 1.0)
        values[name] = float(centre * np.exp(sd * rng.standard_normal()))
    values["relax_frac"] = min(values["relax_frac"], 0.8)
    values["relax_frac2"] = min(values["relax_frac2"], 0.8)
    values["f_static_excess"] = values["f_kin"] * min(values.pop("static_ratio", 0.0), 1.5)
    return values
