"""The grip as a observed input of a FabricSlide slide: the normal load and its scaling laws.

**The load.** The grip loop closes or opens the gripper until the trimmed mean of
the 16 taxels (largest and smallest dropped) equals its set-point, so that trimmed
mean, averaged over the constant-speed part, measures the normal load of a slide
(:func:`grip_load`, counts). Its variation in time, the plain mean over the taxels
(:func:`load_signal`), is what each taxel follows as the loop re-commands the
gripper; :func:`without_load` takes out of each taxel its least-squares response
to it, leaving what the taxels do beyond following the load (the texture). The
variation and the residual are unchanged by a constant added to any taxel; the
load level is not (it is the level itself).

**Offset-free measures of the load.** Sliding shifts load between the taxels (the
shear the fabric exerts, the pad's creep under the grip), the more the larger the
normal load. The stroke shift (:func:`stroke_shift`, counts) is each taxel's mean over
the end ramp (the finger slowing to rest) minus its mean over the start ramp (the
finger starting from rest), with the change common to all taxels removed: the load
pattern the stroke leaves behind. The breakaway shift (:func:`breakaway_shift`,
counts) is each taxel's mean over the steady part minus its mean over the first
:data:`BREAKAWAY_FRACTION` of the slide (while the finger still sticks and starts to
move), likewise. As differences of each taxel with itself, both are unchanged by a
constant added to any taxel.

**Scaling laws.** A quantity ``q`` observed at loads ``L`` follows a power law
``q = c L^b`` (``log q`` linear in ``log L``). :class:`GripLaw` fits one exponent per
quantity, common to the classes and fitted within each class across the training
grips (class intercepts free), and gives each quantity at a reference load:
``log q - b (log L - log L_ref)``, so a slide at a new grip is compared through the
law instead of as an unseen point. :func:`law_support` compares candidate laws per
class by how well each predicts a grip left out of the fit.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from sklearn.base import BaseEstimator, TransformerMixin
from sklearn.utils.validation import check_is_fitted

from frictionfit.datasets.fabricslide import TAXELS
from frictionfit.errors import RecordingError
from frictionfit.recording import Recording

__all__ = ["BREAKAWAY_FRACTION", "LAWS", "RAMP_FRACTION", "GripLaw", "breakaway_shift",
           "grip_load", "law_curve", "law_support", "load_signal", "steady_part",
           "stroke_shift", "without_load"]

#: Fraction of a slide taken by each velocity ramp when the metadata lacks ``ramp_s``.
RAMP_FRACTION = 0.079
#: Fraction of a slide (from its start) whose taxel means are the reference of the
#: breakaway shift.
BREAKAWAY_FRACTION = 0.03
#: Candidate laws of a quantity against the load L (counts), by name: exponent of L in
#: ``log q = a + b log L`` (None: fitted), or ``"linear"`` (``q = a + b L``).
LAWS: dict[str, float | str | None] = {
    "constant": 0.0,          # the grip changes nothing
    "hertz": 1.0 / 3.0,       # a contact stiffness or radius, Hertzian contact
    "per_unit_load": 1.0,     # a friction-like force: proportional to the load
    "power": None,            # exponent fitted
    "linear": "linear",       # q = a + b L
}


def _ramp_s(rec: Recording) -> float:
    return float(rec.metadata.get("ramp_s", RAMP_FRACTION * rec.duration_s))


def steady_part(rec: Recording) -> np.ndarray:
    """Where the slide runs at constant speed: outside both velocity ramps (``ramp_s`` s;
    :data:`RAMP_FRACTION` of the slide each where the metadata lacks it)."""
    ramp_s = _ramp_s(rec)
    return (rec.t >= ramp_s) & (rec.t <= rec.t[-1] - ramp_s)


def grip_load(rec: Recording) -> float:
    """The normal load of a slide (counts): trimmed mean of the taxels' steady-part means.

    The largest and the smallest taxel mean are dropped, as the grip loop drops them.
    """
    keep = steady_part(rec)
    if keep.sum() < 2:
        raise RecordingError("no samples at constant speed to measure the grip load",
                             path=rec.name)
    means = np.sort([rec.channel(c)[keep].mean() for c in TAXELS])
    load = float(means[1:-1].mean())
    if not np.isfinite(load) or load <= 0:
        raise RecordingError(f"grip load {load:.3g} counts is not positive", path=rec.name)
    return load


def breakaway_shift(rec: Recording) -> float:
    """The load shifted between the taxels as the slide starts (counts): the Euclidean norm
    over the taxels of (steady-part mean minus mean over the first
    :data:`BREAKAWAY_FRACTION` of the samples, at least 3), the mean over taxels removed."""
    keep = steady_part(rec)
    x = np.column_stack([rec.channel(c) for c in TAXELS])
    start = max(3, int(round(BREAKAWAY_FRACTION * x.shape[0])))
    if keep.sum() < 2 or start >= x.shape[0]:
        raise RecordingError("too few samples to measure the breakaway shift", path=rec.name)
    d = x[keep].mean(axis=0) - x[:start].mean(axis=0)
    shift = float(np.linalg.norm(d - d.mean()))
    if not np.isfinite(shift) or shift <= 0:
        raise RecordingError(f"breakaway shift {shift:.3g} counts is not positive",
                             path=rec.name)
    return shift


def stroke_shift(rec: Recording) -> float:
    """The load shifted between the taxels over the stroke (counts): the Euclidean norm over
    the taxels of (mean over the end ramp minus mean over the start ramp, each ``ramp_s``
    s as in :func:`steady_part`, at least 3 samples), the mean over taxels removed."""
    x = np.column_stack([rec.channel(c) for c in TAXELS])
    n = max(3, int(np.count_nonzero(rec.t < _ramp_s(rec))))
    if 2 * n > x.shape[0]:
        raise RecordingError("too few samples to measure the stroke shift", path=rec.name)
    d = x[-n:].mean(axis=0) - x[:n].mean(axis=0)
    shift = float(np.linalg.norm(d - d.mean()))
    if not np.isfinite(shift) or shift <= 0:
        raise RecordingError(f"stroke shift {shift:.3g} counts is not positive", path=rec.name)
    return shift


def load_signal(x: np.ndarray) -> np.ndarray:
    """The load's variation in time: the mean over taxels (columns), centred (counts)."""
    n = x.mean(axis=1)
    return n - n.mean()


def without_load(x: np.ndarray) -> np.ndarray:
    """Each centred taxel (column) minus its least-squares response to :func:`load_signal`."""
    xc = x - x.mean(axis=0)
    n = load_signal(xc)
    nn = float(n @ n)
    if nn <= 0:
        return xc
    return xc - np.outer(n, (n @ xc) / nn)


def _within(values: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """``values`` (rows) minus the mean of their group."""
    out = np.array(values, dtype=np.float64, copy=True)
    for g in np.unique(groups):
        rows = groups == g
        out[rows] -= out[rows].mean(axis=0)
    return out


class GripLaw(TransformerMixin, BaseEstimator):
    """Quantities brought to a reference load by power laws fitted across the training grips.

    ``fit(Q, y, log_load=...)`` fits, per column ``j`` of ``Q`` (already logs of positive
    quantities, or quantities taken as linear in ``log L``), ``Q_j = a_{class,j} + b_j
    log L``: one exponent ``b_j`` common to the classes, the intercepts per class,
    by least squares on the rows centred within each class. ``transform(Q,
    log_load=...)`` returns ``Q_j - b_j (log L - log L_ref)``, ``L_ref`` the training
    rows' geometric mean load. Without classes (``y=None``) the exponents are zero: load
    and class cannot be told apart.

    Attributes
    ----------
    exponents_ : ndarray of shape (n_columns,)
    log_load_ref_ : float
    """

    def fit(self, Q, y=None, *, log_load) -> GripLaw:
        Q = np.asarray(Q, dtype=np.float64)
        log_load = np.asarray(log_load, dtype=np.float64)
        if log_load.shape != (Q.shape[0],) or not np.all(np.isfinite(log_load)):
            raise ValueError(f"log_load needs one finite value per row ({Q.shape[0]}), "
                             f"got shape {log_load.shape}")
        self.log_load_ref_ = float(log_load.mean())
        self.exponents_ = np.zeros(Q.shape[1])
        if y is not None:
            groups = np.asarray(y).astype(str)
            lc = _within(log_load[:, None], groups)[:, 0]
            qc = np.where(np.isfinite(Q), _within(np.nan_to_num(Q), groups), 0.0)
            if float(lc @ lc) > 0:
                self.exponents_ = (lc @ qc) / float(lc @ lc)
        return self

    def transform(self, Q, *, log_load) -> np.ndarray:
        check_is_fitted(self, "exponents_")
        Q = np.asarray(Q, dtype=np.float64)
        shift = np.asarray(log_load, dtype=np.float64) - self.log_load_ref_
        return Q - np.outer(shift, self.exponents_)


def _law_fit(law, log_l: np.ndarray, q: np.ndarray):
    """Coefficients ``(a, b)`` of one law on one class's points, in its own coordinates."""
    if law == "linear":
        return np.polyfit(np.exp(log_l), q, 1)[::-1]
    if law is None:
        return np.polyfit(log_l, q, 1)[::-1] if np.ptp(log_l) > 0 else (q.mean(), 0.0)
    return (float(np.mean(q - law * log_l)), law)


def _law_predict(law, coef, log_l: np.ndarray) -> np.ndarray:
    a, b = coef
    return a + b * (np.exp(log_l) if law == "linear" else log_l)


def law_curve(law: str, log_load: np.ndarray, q: np.ndarray, at: np.ndarray) -> np.ndarray:
    """The law named ``law`` (a key of :data:`LAWS`) fitted to ``q`` against ``log_load``
    (natural log of counts), by least squares, evaluated at the log loads ``at``."""
    if law not in LAWS:
        raise ValueError(f"unknown law {law!r}; choose from {list(LAWS)}")
    log_load, q = np.asarray(log_load, dtype=np.float64), np.asarray(q, dtype=np.float64)
    return _law_predict(LAWS[law], _law_fit(LAWS[law], log_load, q), np.asarray(at, float))


def law_support(table: pd.DataFrame, quantities: list[str], *, by: str = "fabric",
                grip: str = "pressure", log_load: str = "log_load") -> pd.DataFrame:
    """Held-out error of each law (:data:`LAWS`) per class and quantity.

    For each class (``by``) and quantity (a column of ``table``, in log units where the
    laws are power laws), every grip set-point (``grip``) is left out in turn; each law is
    fitted to the class's rows at the other grips (against ``log_load``, natural log of
    the load in counts) and predicts the median of the left-out rows at their median
    load. Laws that need two grips to fit (``power``, ``linear``) need three grips in all.

    Returns
    -------
    DataFrame
        One row per class, quantity and law: ``rmse`` (root mean square of the held-out
        errors over the left-out grips), ``exponent`` (fitted on all the class's grips;
        the slope for ``linear``), ``mse_se`` (standard error of the mean square error
        over the left-out grips), ``n_grips``, ``n_params`` and ``best``: for that class and
        quantity, the law with the fewest parameters whose mean square error is within
        one standard error of the smallest.
    """
    rows = []
    for cls, name in ((c, q) for c in sorted(table[by].unique()) for q in quantities):
        part = table[table[by] == cls]
        g = part.groupby(grip).agg(q=(name, "median"), l=(log_load, "median")).dropna()
        for law_name, law in LAWS.items():
            needs = 3 if law is None or law == "linear" else 2
            if len(g) < needs:
                continue
            ls, qs = g["l"].to_numpy(), g["q"].to_numpy()
            errs = [qs[i] - _law_predict(law, _law_fit(law, np.delete(ls, i), np.delete(qs, i)),
                                         ls[i]) for i in range(len(g))]
            coef = _law_fit(law, ls, qs)
            rows.append({by: cls, "quantity": name, "law": law_name,
                         "rmse": float(np.sqrt(np.mean(np.square(errs)))),
                         "mse_se": float(np.std(np.square(errs)) / np.sqrt(len(errs))),
                         "exponent": float(coef[1]), "n_grips": len(g)})
    out = pd.DataFrame(rows)
    if not out.empty:
        out["n_params"] = [2 if LAWS[law] is None or LAWS[law] == "linear" else 1
                           for law in out["law"]]
        best = {key: _simplest(part) for key, part in out.groupby([by, "quantity"])}
        out["best"] = [best[key] for key in zip(out[by], out["quantity"], strict=True)]
    return out


def _simplest(part: pd.DataFrame) -> str:
    """The law with the fewest parameters whose held-out mean square error is within one
    standard error of the smallest (the one-standard-error rule; :data:`LAWS` order among
    equals)."""
    i = part["rmse"].idxmin()
    near = part[part["rmse"] ** 2 <= part.loc[i, "rmse"] ** 2 + part.loc[i, "mse_se"]]
    return str(near.sort_values("n_params", kind="stable")["law"].iloc[0])
