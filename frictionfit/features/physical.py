"""Physical features: fitted contact-model parameters and contact quantities read off the force.

For each non-preparatory motion and force channel of a rubbing measurement:

**Fitted** (``fitted=True``): the whole measurement of each force channel along the
rubbing direction (``thumb_x``, ``index_x``) is fitted at once by
:func:`frictionfit.fit_recordings` (rig, sensor and one contact law,
the law's state carried from stroke to stroke; ``decimate`` samples per point while the
finger moves).
Kept, in log10 where positive: ``k`` (N/mm of fingertip travel where every recording
declares its rig's stroke, ``metadata.stroke_mm``; N per stroke, and named so, where none
does; a mix is an error: the two do not compare), the static
friction level ``f_static = f_kin + f_static_excess`` (N), and what the fit derives
(:mod:`frictionfit.fit.derived`): the held force ``f_held`` (N), the peak force ``f_peak``
(N) and the ``onset_rate`` (N/s) as the sensor sees them, and the stick-slip intensity
``slip_noise`` (N, floored at :data:`SLIP_FLOOR_N`); with ``relaxation=True`` also
``relax_frac`` (1), ``tau`` (s) and ``drag`` (N s/mm, or N s/stroke as ``k``); never the
sensor's offset, drift or leak, nor the rig's motor timing or creep.
``with_stderr=True`` adds each one's standard error (of the log10 where logged).
Each lateral channel (``thumb_y``, ``index_y``, with its finger's rubbing channel) gets
what :func:`frictionfit.fit.lateral.fit_lateral` finds: the ``gain`` (1, the lateral force
over the fitted tangential force, signed) and the lateral stick-slip ``slip_noise`` (N,
floored as the rubbing channels'); never the lateral sensor's offset, drift or leak.

**Read off the force** (``measured=True``), per movement phase (``out``, ``back``), from the
signal after a centred moving average over :data:`FILTER_S`, relative to its value ``x0``
at the command (so offset-free): ``rise`` (N, the peak deviation within :data:`PEAK_S` of
the command, signed), ``static`` (N, the deviation at the end of the relaxation),
``relaxed_frac`` (1, ``1 - static / rise``: the share of the peak that relaxes;
gain-free), ``t_relax`` (s, from the peak until the deviation has covered
:data:`RELAXED_SHARE` of the way to its final level: a model-free relaxation time),
``onset_rate`` (N/s, the largest slope between the command and the peak: loading
stiffness times drive speed) and ``t_peak`` (s); ``slip_ripple`` (1, the standard
deviation of the signal minus its :data:`RIPPLE_SMOOTH_S` moving average within
:data:`RIPPLE_S` of the command, over ``|rise|``: stick-slip oscillation) and the
normalised relaxation curve ``relax_<ms>ms`` (1, the deviation :data:`RELAX_DELAYS` after
the peak over ``rise``). The ratios are gain-free. The
relaxation quantities (``relaxed_frac``, ``t_relax``, ``relax_<ms>ms``) are kept only with
``relaxation=True``.

**Missing values.** A trial whose fit fails (any status but CONVERGED and
ILL_CONDITIONED, whose values stand though some may be poorly determined; and
MAX_STEPS unless ``accept_max_steps``) gives NaN parameters; NaN samples are
masked in the fit and skipped by the measurements. A measurement's value is the
median over its motions ignoring NaN; where every motion is NaN the base class
fills the training median and warns (:class:`~frictionfit.features._base.FeatureWarning`).

FabricSlide slides are not rubbing measurements: their physical features are the
``sliding`` set (:class:`frictionfit.features.sliding.SlidingPhysicalFeatures`); given
here, they raise a ValueError that says so.
"""

from __future__ import annotations

import re
import warnings
from collections.abc import Sequence

import numpy as np

from frictionfit.errors import RecordingError, Status
from frictionfit.features._base import FeatureWarning, RecordingFeatures, _as_list
from frictionfit.features._rubbing import (
    PHASES,
    RUBBING_CHANNELS,
    channel_samples,
    command_times,
    motions,
)
from frictionfit.models import PARAMS
from frictionfit.recording import Recording
from frictionfit.segmentation import Motion, moving_average

__all__ = ["FITTED", "FITTED_CHANNELS", "LATERAL_CHANNELS", "LATERAL_KEPT", "MEASURED",
           "SLIP_FLOOR_N", "FittedFeatures", "PhysicalFeatures", "measured_phase"]

#: Fitted quantities kept (log10 of the positive ones): the law's parameters, with the
#: static friction level ``f_static = f_kin + f_static_excess`` in place of the two (where
#: the force droops over the whole stroke, their split is not identified; their sum is).
FITTED = ("k", "f_static", "f_held", "f_peak", "onset_rate", "slip_noise", "relax_frac", "tau",
          "drag")
_DERIVED_UNITS = {"f_static": "N", "f_held": "N", "f_peak": "N", "onset_rate": "N/s",
                  "slip_noise": "N"}
#: Fitted quantities per unit of fingertip travel: per mm where the stroke is declared.
_PER_TRAVEL = ("k", "drag")
_STDERR = "_stderr ["  # marks a standard error's column: ``<name>_stderr [<unit>]``
#: The smallest ``slip_noise`` told apart (N): the sensor's resolution, about 1 mN.
SLIP_FLOOR_N = 1e-3
#: Channels whose force follows the contact law (fitted).
FITTED_CHANNELS = ("thumb_x", "index_x")
#: Lateral channel -> the rubbing channel whose fitted force it is fitted on.
LATERAL_CHANNELS = {"thumb_y": "thumb_x", "index_y": "index_x"}
#: What the lateral fit gives that is kept as features (:mod:`frictionfit.fit.lateral`;
#: ``slip_noise`` in log10, floored at :data:`SLIP_FLOOR_N` as the rubbing channels' is).
LATERAL_KEPT = ("gain", "slip_noise")
#: Measured quantities per phase and their units.
MEASURED = (("rise", "N"), ("static", "N"), ("relaxed_frac", "1"), ("t_relax", "s"),
            ("onset_rate", "N/s"), ("t_peak", "s"), ("slip_ripple", "1"),
            ("relax_50ms", "1"), ("relax_100ms", "1"), ("relax_200ms", "1"),
            ("relax_400ms", "1"))
#: The first six are the basic quantities; the shape quantities follow (``shape=True``).
N_BASIC = 6
#: Names of the relaxation quantities (after the channel), left out with ``relaxation=False``:
#: fitted ``relax_frac``, ``tau`` and ``drag``; measured ``relaxed_frac``, ``t_relax`` and
#: ``relax_<ms>ms``.
_RELAXATION = re.compile(r"^(fit_(relax_frac|tau|drag)(_stderr)?\b"
                         r"|(out|back)_(relaxed_frac|t_relax|relax_\d+ms)\b)")
#: Delays after the peak (s) of the normalised relaxation curve ``relax_<ms>ms``.
RELAX_DELAYS = (0.05, 0.1, 0.2, 0.4)
#: Window (s) after the command in which the stick-slip ripple is read.
RIPPLE_S = 0.25
#: Window (s) after the command in which the peak (``rise``) is read.
PEAK_S = 0.3
#: Share of the way from the peak to the final level at which ``t_relax`` is read (about
#: ``1 - 1/e``: one time constant of an exponential relaxation).
RELAXED_SHARE = 0.63
#: Spans (s) of the moving averages: the signal's filter, and the ripple's smooth part.
#: Each is taken over the odd number of samples nearest it at the recording's rate, so
#: a quantity means the same at every sample rate.
FILTER_S, RIPPLE_SMOOTH_S = 0.009, 0.025


def samples_over(span_s: float, rate_hz: float) -> int:
    """The odd number of samples nearest ``span_s`` (s) at ``rate_hz`` (at least 1)."""
    return 2 * int(0.5 * span_s * rate_hz) + 1


def measured_phase(x: np.ndarray, rate_hz: float, i_cmd: int, i_end: int,
                   peak_samples: int) -> np.ndarray:
    """The :data:`MEASURED` quantities of one phase of one (filtered) channel.

    ``x``: the motion's signal (N, NaN where missing); ``i_cmd``: the command's
    sample; ``i_end``: the phase end (exclusive); ``peak_samples``: the peak window.
    """
    out = np.full(len(MEASURED), np.nan)
    idx = np.flatnonzero(np.isfinite(x[i_cmd:i_end])) + i_cmd
    window = idx[idx < i_cmd + peak_samples]
    if window.size < 2:
        return out
    dev = x - x[idx[0]]
    i_peak = window[np.argmax(np.abs(dev[window]))]
    rise, static = dev[i_peak], dev[idx[-1]]
    loading = idx[idx <= i_peak]
    slopes = np.abs(np.diff(dev[loading]) / np.diff(loading)) * rate_hz
    after = idx[idx >= i_peak]
    target = rise - RELAXED_SHARE * (rise - static)
    crossed = after[np.sign(rise) * (dev[after] - target) <= 0]
    if rise == 0:
        return out
    ripple = idx[idx < i_cmd + int(round(RIPPLE_S * rate_hz))]
    smooth = moving_average(dev[ripple], samples_over(RIPPLE_SMOOTH_S, rate_hz))
    curve = [dev[i] / rise if i < i_end and np.isfinite(dev[i]) else np.nan
             for i in (i_peak + np.round(np.asarray(RELAX_DELAYS) * rate_hz).astype(int))]
    out[:] = [
        rise,
        static,
        1.0 - static / rise,
        (crossed[0] - i_peak) / rate_hz if crossed.size else np.nan,
        slopes.max() if slopes.size else np.nan,
        (i_peak - i_cmd) / rate_hz,
        np.std(dev[ripple] - smooth) / abs(rise) if ripple.size else np.nan,
        *curve,
    ]
    return out


def _rubbing_only(recordings: Sequence[Recording]) -> None:
    """ValueError naming the first FabricSlide slide among ``recordings``."""
    for r in recordings:
        if r.metadata.get("dataset") == "fabricslide":
            raise ValueError(f"{r.name}: a FabricSlide slide, not a rubbing measurement; its "
                             "physical features are the 'sliding' set")


class PhysicalFeatures(RecordingFeatures):
    """Fitted contact-model parameters and contact quantities read off the force, per channel.

    Parameters
    ----------
    fitted : bool, default False
        Include the fitted quantities (see the module notes): a whole-measurement fit per
        recording.
    measured : bool, default True
        Include the quantities read off the force per movement phase.
    shape : bool, default True
        Include the gain-free shape quantities (``slip_ripple``, ``relax_<ms>ms``).
    model : str, default "relaxation2"
        Contact law of the measurement fit (``frictionfit.models.measurement.LAWS``), or
        ``"auto"`` (no static peak, a static peak, or one with damping, by BIC).
    rig : {"recording", "session"}, default "recording"
        Where the motor's profile is fitted: per recording, or once per session (the median
        over the session's recordings featurised together).
    creep : {"recording", "session"}, default "recording"
        Where the finger's creep (the slow relaxation branch's time constant) is fitted: per
        recording (its features depend on it alone), or once per session and channel, the
        median over the session's recordings featurised together (each session is one batch;
        a recording alone in its session keeps its own). With either at ``"session"`` a
        recording's features depend on the session's recordings featurised with it:
        featurise a session in one call.
    relaxation : bool, default False
        Include the relaxation quantities: fitted ``relax_frac``, ``tau`` and ``drag``, and
        ``relaxed_frac``, ``t_relax`` and ``relax_<ms>ms`` read off the force.
    decimate : int, default 1
        Samples averaged per fitted point while the finger moves (while it holds: the
        ``coarse`` blocks of :func:`~frictionfit.fit.measurement_data.measurement_data`).
    max_steps : int, default 200
        Solver step budget per trial.
    accept_max_steps : bool, default True
        Keep the last iterate of fits that ran out of steps (status MAX_STEPS); False
        makes their values NaN.
    with_stderr : bool, default False
        Add the fitted parameters' standard errors.
    channels : tuple of str
        Force channels to use, by name.
    wear : bool, default False
        Fit the kinetic level's ``wear`` over the measurement (the whole fits do by
        default); held at 0 otherwise.
    cache : bool, default True
        Cache rows by recording content.

    Examples
    --------
    >>> PhysicalFeatures(fitted=False).get_feature_names_out()[0]
    'thumb_x:out_rise [N]'
    """

    _version = 33  # the cached rows' layout and meaning: raised whenever either changes
    _view_params = ("with_stderr", "relaxation")  # both are stored either way
    #: Recordings per batched fit: 64 x 2 rubbing channels keep the solver's pools of 16
    #: refilled (with a hold at the session's, a session is one batch, :meth:`_blocks`).
    _block = 64

    def __init__(self, fitted: bool = False, measured: bool = True, shape: bool = True,
                 model: str = "relaxation2", rig: str = "recording", creep: str = "recording",
                 relaxation: bool = False, decimate: int = 1, max_steps: int = 200,
                 accept_max_steps: bool = True, with_stderr: bool = False,
                 channels: tuple[str, ...] = RUBBING_CHANNELS, wear: bool = False,
                 cache: bool = True):
        self.fitted = fitted
        self.measured = measured
        self.shape = shape
        self.model = model
        self.rig = rig
        self.creep = creep
        self.relaxation = relaxation
        self.decimate = decimate
        self.max_steps = max_steps
        self.accept_max_steps = accept_max_steps
        self.with_stderr = with_stderr
        self.channels = channels
        self.wear = wear
        self.cache = cache

    # --- names -------------------------------------------------------------
    @staticmethod
    def _fitted_names() -> list[str]:
        """Each fitted quantity, then its standard error (both cached; see :meth:`_names`)."""
        names = []
        for p in FITTED:
            unit = _DERIVED_UNITS.get(p) or PARAMS[p].unit
            unit = f"log10 {unit}" if p in _DERIVED_UNITS or PARAMS[p].transform == "loglogit" \
                else unit
            names += [f"{p} [{unit}]", f"{p}{_STDERR}{unit}]"]
        return names

    @staticmethod
    def _lateral_names() -> list[str]:
        """Each kept lateral coefficient, then its standard error (both cached)."""
        from frictionfit.fit.lateral import LATERAL_UNITS

        units = {p: "log10 N" if p == "slip_noise" else LATERAL_UNITS[p] for p in LATERAL_KEPT}
        return [n for p in LATERAL_KEPT for n in (f"{p} [{units[p]}]", f"{p}{_STDERR}{units[p]}]")]

    def _fitted_channel_names(self, ch: str) -> list[str]:
        """The fitted columns of channel ``ch`` (none where it is not fitted)."""
        if not self.fitted:
            return []
        if ch in FITTED_CHANNELS:
            return self._fitted_names()
        if LATERAL_CHANNELS.get(ch) in self.channels:
            return self._lateral_names()
        return []

    def _names(self) -> list[str]:
        return [n for n in self._stored_names()
                if (self.with_stderr or _STDERR not in n)
                and (self.relaxation or not _RELAXATION.search(n.partition(":")[2]))]

    def _blocks(self, recordings: Sequence[Recording], missing: list[int]) -> list[list[int]]:
        """Runs of :attr:`_block` recordings; with a hold at the session's, each session's
        recordings in one batch (the hold is their median)."""
        if not self.fitted or (self.rig, self.creep) == ("recording", "recording"):
            return super()._blocks(recordings, missing)
        sessions: dict[str, list[int]] = {}
        for i in missing:
            sessions.setdefault(str(recordings[i].session), []).append(i)
        return list(sessions.values())

    def _stored_names(self) -> list[str]:
        names = []
        for ch in self.channels:
            names += [f"{ch}:fit_{n}" for n in self._fitted_channel_names(ch)]
            if self.measured:
                names += [f"{ch}:{p}_{n} [{u}]" for p in PHASES for n, u in self._measured_kept()]
        if not names:
            raise ValueError("physical features: set fitted and/or measured")
        return names

    def get_feature_names_out(self, input_features=None) -> np.ndarray:
        """Readable feature names with units; ``k`` and ``drag`` per stroke (``N/stroke``,
        ``N s/stroke``) where the training recordings declare no stroke."""
        names = self._names()
        if getattr(self, "stroke_declared_", True) is False:
            names = [_per_stroke(n) for n in names]
        return np.asarray(names, dtype=object)

    def _rows(self, recordings: Sequence[Recording]) -> np.ndarray:
        recordings = _as_list(recordings)
        declared = _stroke_declared(recordings) if self.fitted else None
        trained = getattr(self, "stroke_declared_", None)
        if declared is not None and trained is not None and declared != trained:
            raise ValueError(
                "physical features: trained on recordings that " + (
                    "declare their rig's stroke (k in N/mm); these do not (declare "
                    "metadata.stroke_mm)" if trained else
                    "declare no stroke (k in N/stroke); these declare one: retrain"))
        return super()._rows(recordings)

    def _fit_rows(self, rows: np.ndarray, X: Sequence[Recording]) -> None:
        super()._fit_rows(rows, X)
        self.stroke_declared_ = _stroke_declared(_as_list(X)) if self.fitted else None

    def _measured_kept(self) -> tuple[tuple[str, str], ...]:
        return MEASURED if self.shape else MEASURED[:N_BASIC]

    def _spread(self, draws: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Each fitted feature drawn from its fit's posterior (Laplace: normal about the
        fitted value with its standard error, of the log10 where logged). A value whose
        standard error is not finite, or exceeds the spread of that feature over the
        training recordings, tells the recordings apart no better than chance: it is left
        to the training values (NaN here, drawn by ``_drawn_where_missing``)."""
        stored, names = self._stored_names(), self._names()
        draws = draws.copy()
        for e, name in enumerate(stored):
            value_name = name.replace(_STDERR, " [")
            if _STDERR not in name or value_name not in names:
                continue
            j, v = names.index(value_name), stored.index(value_name)
            seen = self.training_rows_[:, j][np.isfinite(self.training_rows_[:, j])]
            spread = np.std(seen) if seen.size > 1 else 0.0
            se = draws[..., e]
            informative = np.isfinite(se) & (se <= spread)
            noise = rng.standard_normal(se.shape) * np.where(informative, se, 0.0)
            draws[..., v] = np.where(informative, draws[..., v] + noise, np.nan)
        return draws

    # --- extraction ----------------------------------------------------------
    def _motion_rows(self, recordings: Sequence[Recording]) -> list[np.ndarray | None]:
        _rubbing_only(recordings)  # every extraction (rows, draws) comes through here
        found: list[list[Motion] | None] = []
        for rec in recordings:
            try:
                found.append(motions(rec, self.channels,
                                     filter_n=samples_over(FILTER_S, rec.sample_rate_hz)))
            except RecordingError as exc:
                warnings.warn(f"physical features: {exc}", FeatureWarning, stacklevel=2)
                found.append(None)
        fits = self._fit_all(recordings) if self.fitted else None
        out: list[np.ndarray | None] = []
        for i, ms in enumerate(found):
            if not ms:
                out.append(None)
                continue
            rows = []
            for m in ms:
                row = []
                for j, ch in enumerate(self.channels):
                    width = len(self._fitted_channel_names(ch))
                    if fits is not None and width:
                        row.append(fits[i].get(ch, np.full(width, np.nan)))
                    if self.measured:
                        row.append(self._measured(m, j))
                rows.append(np.concatenate(row))
            out.append(np.stack(rows))
        return out

    def _measured(self, m: Motion, j: int) -> np.ndarray:
        x = channel_samples(m, self.channels)[:, j]
        rate = m.sample_rate_hz
        cmd = {p: int(round(s * rate)) for p, s in command_times(m).items()}
        ends = {"out": cmd["back"], "back": x.shape[0]}
        n, peak = len(self._measured_kept()), int(round(PEAK_S * rate))
        return np.concatenate([measured_phase(x, rate, cmd[p], ends[p], peak)[:n]
                               for p in PHASES])

    def _fit_all(self, recordings: Sequence[Recording]) -> list[dict[str, np.ndarray]]:
        """Per recording, channel -> row of fitted features, from one whole-measurement fit
        of every (recording, fitted channel) in one batch (NaN rows where a fit failed)."""
        from frictionfit.fit.measurement_data import measurement_data
        from frictionfit.whole_fit import fit_recordings

        width = len(self._fitted_names())
        fitted = [c for c in self.channels if c in FITTED_CHANNELS]
        items, where = [], []
        for i, rec in enumerate(recordings):
            for ch in fitted:
                try:
                    items.append(measurement_data(rec, ch, decimate=self.decimate))
                    where.append((i, ch))
                except ValueError as exc:
                    warnings.warn(f"physical features: {exc}", FeatureWarning, stacklevel=3)
        out: list[dict[str, np.ndarray]] = [{} for _ in recordings]
        if not items:
            return out
        # no second start from the session's profile of the batch: with rig="recording" a
        # recording's row depends on it alone (and is cached by its content)
        res = fit_recordings(items, model=self.model, rig=self.rig, creep=self.creep,
                             max_steps=self.max_steps,
                             fix=None if self.wear else {"wear": 0.0}, refit_rig_outliers=False,
                             progress=False)  # the feature set's own bar counts the batches
        ok = {Status.CONVERGED, Status.ILL_CONDITIONED}
        if self.accept_max_steps:
            ok.add(Status.MAX_STEPS)
        for k, (i, ch) in enumerate(where):
            good = Status(int(res.status[k])) in ok
            per_mm = res.stroke_mm / (items[k].stroke_mm or 1.0)  # travel unit -> mm
            out[i][ch] = (np.asarray(self._fitted_row(res.params(k), res.stderrs(k),
                                                      res.derived[k], per_mm)) if good
                          else np.full(width, np.nan))
            lateral = next((c for c, of in LATERAL_CHANNELS.items()
                            if of == ch and c in self.channels), None)
            if good and lateral is not None:
                out[i][lateral] = self._lateral_row(recordings[i], lateral, res, k)
        return out

    def _lateral_row(self, rec: Recording, channel: str, res, k: int) -> np.ndarray:
        """The kept lateral coefficients of ``channel`` and their standard errors, on trial
        ``k`` of the rubbing channels' fit ``res`` (NaN where the channel cannot be read)."""
        from frictionfit.fit.lateral import fit_lateral
        from frictionfit.fit.measurement_data import measurement_data

        try:
            d = measurement_data(rec, channel, decimate=self.decimate)
        except ValueError as exc:
            warnings.warn(f"physical features: {exc}", FeatureWarning, stacklevel=4)
            return np.full(len(self._lateral_names()), np.nan)
        got = fit_lateral(res.member(k), res.u[k], res.items[k].drive, float(res.direction[k]),
                          d)
        noise, se = got["slip_noise"]
        noise = max(noise, SLIP_FLOOR_N) if np.isfinite(noise) else noise
        got["slip_noise"] = (np.log10(noise), se / (noise * np.log(10)))
        return np.array([v for p in LATERAL_KEPT for v in got[p]])

    def _fitted_row(self, values: dict, stderr: dict, derived: dict,
                    per_mm: float = 1.0) -> list[float]:
        """Log10 of the positive parameters, each followed by its stderr (of the log10);
        the per-travel ones (``k``, ``drag``) times ``per_mm`` (fit's travel unit over the
        declared stroke)."""
        values, stderr = dict(values), dict(stderr)
        for name in _PER_TRAVEL:
            values[name], stderr[name] = values[name] * per_mm, stderr[name] * per_mm
        for name, (v, se) in derived.items():
            values[name], stderr[name] = v, se
        values["slip_noise"] = max(values["slip_noise"], SLIP_FLOOR_N)
        row = []
        for p in FITTED:
            logged = p in _DERIVED_UNITS or PARAMS[p].transform == "loglogit"
            row += ([np.log10(values[p]), stderr[p] / (values[p] * np.log(10))] if logged
                    else [values[p], stderr[p]])
        return row


def _stroke_declared(recordings: Sequence[Recording]) -> bool | None:
    """Whether every recording declares its rig's stroke (None: no recordings); ValueError
    naming those without it where only some do (their ``k`` would not compare)."""
    declared = [r.stroke_mm is not None for r in recordings]
    if any(declared) and not all(declared):
        missing = [r.name for r, d in zip(recordings, declared, strict=True) if not d]
        raise ValueError(f"physical features: {len(missing)} recording(s) declare no rig "
                         f"stroke (metadata.stroke_mm) where the others do "
                         f"({', '.join(missing[:3])}{', ...' if len(missing) > 3 else ''}): "
                         "k per mm and per stroke do not compare")
    return all(declared) if declared else None


def _per_stroke(name: str) -> str:
    """``name`` of a per-travel feature with its unit per stroke instead of per mm."""
    base = name.split(":")[-1].removeprefix("fit_")
    return name.replace("/mm]", "/stroke]") if base.startswith(_PER_TRAVEL) else name


class FittedFeatures(PhysicalFeatures):
    """The fitted contact-law parameters alone (:class:`PhysicalFeatures` with
    ``fitted=True`` and ``measured=False``)."""

    def __init__(self, fitted: bool = True, measured: bool = False, shape: bool = True,
                 model: str = "relaxation2", rig: str = "recording", creep: str = "recording",
                 relaxation: bool = False, decimate: int = 1, max_steps: int = 200,
                 accept_max_steps: bool = True, with_stderr: bool = False,
                 channels: tuple[str, ...] = RUBBING_CHANNELS, wear: bool = False,
                 cache: bool = True):
        super().__init__(fitted=fitted, measured=measured, shape=shape, model=model, rig=rig,
                         creep=creep, relaxation=relaxation, decimate=decimate,
                         max_steps=max_steps,
                         accept_max_steps=accept_max_steps, with_stderr=with_stderr,
                         channels=channels, wear=wear, cache=cache)
