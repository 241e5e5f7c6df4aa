"""SYNTHETIC touch gestures on a textile pressure-matrix skin, for development and tests.

Not recorded data: every file this module writes says ``"synthetic": true`` in its
metadata. The sensor is a 20 x 20 taxel matrix at 1 cm pitch read at 50 frames/s;
one gesture is a 3-s window (150 frames).

A hand is a set of elliptical Gaussian pressure blobs (palm, finger segments,
fingertips, thumb) in hand coordinates (cm, fingers along +y), scaled by the
person's hand size, rotated and placed on the matrix. Each gesture moves and
loads the blobs in its own way:

=========  ===================================================================
grab       fingertips and thumb curl in towards the palm while pressing
poke       one (or, by personal style, two) fingertip(s), short and sharp
press      flat hand, long hold; force relaxes after the peak
push       palm heel loaded, force ramps up slowly, hand slides forward
scratch    four fingertips oscillate along the finger axis at 3-6 Hz
pinch      thumb and index tip converge while pressing
stroke     flat fingers sweep across the skin, once or twice, lightly
=========  ===================================================================

Each person has a hand size, an overall force, a tempo, a preferred hand angle
and place, and per-gesture habits (force, duration, amplitude, frequency, and
discrete variants such as one- or two-finger pokes). Repetitions vary only a
little around a person's habits, so a classifier trained on the same person
(person-dependent) has an easier task than one facing a new person
(leave-one-person-out). The sensor adds a 30-ms first-order lag, Gaussian noise
(0.3 kPa), clipping at 0 and 100 kPa and 0.1 kPa quantisation.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from frictionfit._types import PathType

__all__ = ["FRAME_RATE_HZ", "GESTURES", "PITCH_CM", "SHAPE", "render_gesture", "simulate_gestures"]

GESTURES = ("grab", "poke", "press", "push", "scratch", "pinch", "stroke")
SHAPE = (20, 20)
PITCH_CM = 1.0
FRAME_RATE_HZ = 50.0
DURATION_S = 3.0
NOISE_KPA = 0.3
SENSOR_LAG_S = 0.03
SATURATION_KPA = 100.0
QUANTUM_KPA = 0.1

# Hand blobs in hand coordinates (cm; palm centre at 0, fingers along +y), for a
# hand of scale 1: name -> (x, y, sigma_x, sigma_y).
_TIPS = {"thumb": (-5.0, 2.5), "index": (-2.4, 7.6), "middle": (-0.7, 8.3),
         "ring": (1.1, 7.9), "little": (2.8, 6.6)}
_TIP_SIGMA = (0.65, 0.75)
_PROX_SIGMA = (0.6, 1.1)
_PALM = (0.0, 0.0, 2.6, 2.6)


def _person(seed: int, person: int) -> dict:
    rng = np.random.default_rng([seed, person, 7])
    habits = {
        g: {
            "force": float(rng.lognormal(0.0, 0.22)),
            "duration": float(rng.lognormal(0.0, 0.22)),
            "amplitude": float(rng.lognormal(0.0, 0.22)),
            "frequency": float(rng.lognormal(0.0, 0.25)),
            "variant": int(rng.integers(2)),
        }
        for g in GESTURES
    }
    return {
        "hand_scale": float(rng.uniform(0.8, 1.2)),
        "force_scale": float(rng.lognormal(0.0, 0.25)),
        "tempo": float(rng.lognormal(0.0, 0.2)),
        "angle_deg": float(rng.uniform(-40.0, 40.0)),
        "place_cm": rng.normal(0.0, 1.5, size=2).tolist(),
        "habits": habits,
    }


def _envelope(t: np.ndarray, onset: float, rise: float, hold: float, fall: float) -> np.ndarray:
    """Raised-cosine trapezoid in [0, 1]: rise, hold, fall (all s) from ``onset`` (s)."""
    up = np.clip((t - onset) / rise, 0.0, 1.0)
    down = np.clip((t - onset - rise - hold) / fall, 0.0, 1.0)
    return 0.5 * (1 - np.cos(np.pi * up)) * 0.5 * (1 + np.cos(np.pi * down))


def _relaxing(t: np.ndarray, t_peak: float, tau: float, plateau: float) -> np.ndarray:
    """1 until ``t_peak``, then relaxing exponentially (``tau`` s) towards ``plateau``."""
    dt = np.clip(t - t_peak, 0.0, None)
    return plateau + (1 - plateau) * np.exp(-dt / tau)


def _tips(T: int, names: list[str], weights: list[float], sig=None) -> tuple[np.ndarray, ...]:
    """Blobs at the named fingertips, still: centres (T, K, 2), sigmas (K, 2), weights (K,)."""
    pts = np.array([_TIPS[n] for n in names], dtype=float)
    c = np.broadcast_to(pts, (T, len(names), 2)).copy()
    s = np.array([sig or _TIP_SIGMA] * len(names), dtype=float)
    return c, s, np.asarray(weights, dtype=float)


def _flat_hand(T: int, palm_w: float, finger_w: float, heel: float = 0.0
               ) -> tuple[np.ndarray, ...]:
    """The palm (``heel`` cm towards the wrist), four proximal phalanges and four tips,
    still: centres (T, 9, 2), sigmas (9, 2), weights (9,)."""
    names = ["index", "middle", "ring", "little"]
    tips = np.array([_TIPS[n] for n in names])
    prox = tips * np.array([1.0, 0.55])
    pts = np.vstack([[[_PALM[0], _PALM[1] - heel]], prox, tips])
    sig = np.vstack([[_PALM[2:]], [_PROX_SIGMA] * 4, [_TIP_SIGMA] * 4])
    w = np.array([palm_w] + [finger_w] * 8)
    return np.broadcast_to(pts, (T, 9, 2)).copy(), sig, w


def _poke(t: np.ndarray, p: dict) -> tuple:
    d, v = p["duration"], p["variant"]
    rise, hold, fall = 0.07 * d, 0.12 * d, 0.09 * d
    env = _envelope(t, p["onset"], rise, hold, fall)
    c, s, w = _tips(t.size, ["index", "middle"][: 1 + v], [1.0, 0.8][: 1 + v])
    return c, s, 55.0 * p["force"] * env[:, None] * w, {"contact_s": rise + hold + fall}


def _press(t: np.ndarray, p: dict) -> tuple:
    d, onset = p["duration"], p["onset"]
    rise, hold, fall = 0.3 * d, 1.3 * d, 0.3 * d
    tau = 0.35 * d
    env = _envelope(t, onset, rise, hold, fall) * _relaxing(t, onset + rise, tau, 0.6)
    c, s, w = _flat_hand(t.size, 1.0, 0.7 + 0.3 * p["variant"])
    return c, s, 22.0 * p["force"] * env[:, None] * w, {
        "contact_s": rise + hold + fall, "relaxation_s": tau, "relax_plateau": 0.6}


def _push(t: np.ndarray, p: dict) -> tuple:
    d, a, onset = p["duration"], p["amplitude"], p["onset"]
    rise, hold, fall = 0.7 * d, 0.6 * d, 0.25 * d
    env = _envelope(t, onset, rise, hold, fall)
    c, s, w = _flat_hand(t.size, 1.4, 0.35, heel=1.5)
    slide = 1.8 * a * np.clip((t - onset) / (rise + hold), 0.0, 1.0)
    c[:, :, 1] += slide[:, None]
    return c, s, 28.0 * p["force"] * env[:, None] * w, {
        "contact_s": rise + hold + fall, "slide_cm": 1.8 * a}


def _grab(t: np.ndarray, p: dict) -> tuple:
    d, a, onset = p["duration"], p["amplitude"], p["onset"]
    rise, hold, fall = 0.35 * d, 0.8 * d, 0.3 * d
    env = _envelope(t, onset, rise, hold, fall)
    names = ["thumb", "index", "middle", "ring", "little"]
    c, s, w = _tips(t.size, names, [1.2, 1.0, 1.0, 0.9, 0.7])
    curl = np.clip((t - onset) / (rise + 0.5 * hold), 0.0, 1.0)[:, None, None]
    c = c * (1 - 0.45 * a * curl)
    palm = np.broadcast_to(np.array(_PALM[:2]), (t.size, 1, 2))
    c = np.concatenate([palm, c], axis=1)
    s = np.vstack([[_PALM[2:]], s])
    w = np.concatenate([[0.35 + 0.3 * p["variant"]], w])
    return c, s, 30.0 * p["force"] * env[:, None] * w, {
        "contact_s": rise + hold + fall, "curl": 0.45 * a}


def _pinch(t: np.ndarray, p: dict) -> tuple:
    d, onset = p["duration"], p["onset"]
    rise, hold, fall = 0.45 * d, 0.45 * d, 0.2 * d
    env = _envelope(t, onset, rise, hold, fall)
    gap0 = 7.0 * p["amplitude"]
    close = np.clip((t - onset) / rise, 0.0, 1.0)
    gap = gap0 - (gap0 - 1.6) * 0.5 * (1 - np.cos(np.pi * close))
    mid = np.array([-3.5, 5.0])
    c = np.empty((t.size, 2, 2))
    c[:, 0] = mid + np.array([-0.6, -0.8]) * gap[:, None] / 2
    c[:, 1] = mid + np.array([0.6, 0.8]) * gap[:, None] / 2
    s = np.array([_TIP_SIGMA, _TIP_SIGMA])
    w = np.array([1.0, 0.9])
    return c, s, 40.0 * p["force"] * env[:, None] * w, {
        "contact_s": rise + hold + fall, "start_gap_cm": gap0}


def _scratch(t: np.ndarray, p: dict) -> tuple:
    onset = p["onset"]
    dur = 1.6 * p["duration"]
    freq = 4.2 * p["frequency"]
    env = _envelope(t, onset, 0.1, dur, 0.1)
    c, s, w = _tips(t.size, ["index", "middle", "ring", "little"], [1.0, 1.0, 0.9, 0.7])
    phase = 2 * np.pi * freq * np.clip(t - onset, 0.0, None)
    c[:, :, 1] += (0.9 * p["amplitude"] * np.sin(phase))[:, None]
    load = 18.0 * p["force"] * (env * (0.75 + 0.25 * np.cos(phase)))[:, None] * w
    return c, s, load, {"contact_s": dur + 0.2, "repetition_hz": freq}


def _stroke(t: np.ndarray, p: dict) -> tuple:
    n = 1 + p["variant"]
    period = 1.1 * p["duration"] / p["frequency"]
    env = np.zeros(t.size)
    sweep = np.zeros(t.size)
    for k in range(n):
        start = p["onset"] + k * period
        env = env + _envelope(t, start, 0.12, 0.75 * period - 0.24, 0.12)
        sweep = sweep + np.where((t >= start) & (t < start + period),
                                 np.clip((t - start) / (0.75 * period), 0.0, 1.0), 0.0)
    c, s, w = _flat_hand(t.size, 0.25, 1.0)
    c[:, :, 1] += (9.0 * p["amplitude"] * (sweep - 0.5))[:, None]
    return c, s, 9.0 * p["force"] * env[:, None] * w, {
        "contact_s": (n - 0.25) * period, "repetition_hz": 1.0 / period, "strokes": n}


#: Each gesture's blobs: ``(t, params) -> (centres, sigmas, loads, truth)``.
_BLOBS = {"poke": _poke, "press": _press, "push": _push, "grab": _grab, "pinch": _pinch,
          "scratch": _scratch, "stroke": _stroke}


def _gesture_blobs(gesture: str, t: np.ndarray, p: dict) -> tuple[np.ndarray, ...]:
    """Blob centres (T, K, 2) and sigmas (K, 2) in hand cm, loads (T, K) in kPa, and truth."""
    if gesture not in _BLOBS:
        raise ValueError(f"unknown gesture {gesture!r}; choose from {GESTURES}")
    return _BLOBS[gesture](t, p)


def render_gesture(
    gesture: str, person: dict, rng: np.random.Generator
) -> tuple[np.ndarray, dict]:
    """Frames (150, 20, 20) in kPa of one repetition of ``gesture`` by ``person``, and truth.

    ``person`` is a dict as drawn for one simulated person (hand size, force, tempo,
    angle, place and per-gesture habits); ``rng`` draws the repetition's variation.
    """
    hab = person["habits"][gesture]
    jitter = rng.lognormal(0.0, 0.08, size=4)
    p = {
        "force": person["force_scale"] * hab["force"] * jitter[0],
        "duration": hab["duration"] * jitter[1] / person["tempo"],
        "amplitude": hab["amplitude"] * jitter[2],
        "frequency": hab["frequency"] * person["tempo"] * jitter[3],
        "variant": hab["variant"],
        "onset": float(rng.uniform(0.15, 0.45)),
    }
    n = int(round(DURATION_S * FRAME_RATE_HZ))
    t = np.arange(n) / FRAME_RATE_HZ
    centres, sigmas, load, truth = _gesture_blobs(gesture, t, p)
    scale = person["hand_scale"]
    angle = np.deg2rad(person["angle_deg"] + rng.normal(0.0, 8.0))
    where = np.array([9.5, 7.5]) + np.asarray(person["place_cm"]) + rng.normal(0.0, 1.0, 2)
    rot = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    rows, cols = SHAPE
    yy, xx = np.mgrid[0:rows, 0:cols] * PITCH_CM
    grid = np.stack([xx.ravel(), yy.ravel()], axis=-1)  # (400, 2), cm
    # taxel offsets from each blob centre, rotated back into hand coordinates
    centre_cm = where + scale * centres @ rot.T  # (T, K, 2)
    diff = (grid[None, None] - centre_cm[:, :, None]) @ rot  # (T, K, 400, 2)
    z = (diff / (scale * sigmas)[None, :, None]) ** 2
    pressure = np.einsum("tk,tkn->tn", load, np.exp(-0.5 * z.sum(-1)))
    # sensor: first-order lag, noise, clipping, quantisation
    alpha = 1.0 - np.exp(-1.0 / (FRAME_RATE_HZ * SENSOR_LAG_S))
    out = np.empty_like(pressure)
    state = np.zeros(pressure.shape[1])
    for i in range(n):
        state = state + alpha * (pressure[i] - state)
        out[i] = state
    out += rng.normal(0.0, NOISE_KPA, out.shape)
    out = np.round(np.clip(out, 0.0, SATURATION_KPA) / QUANTUM_KPA) * QUANTUM_KPA
    truth.update({k: float(v) for k, v in p.items() if k != "variant"}, variant=p["variant"])
    truth.update(angle_deg=float(np.rad2deg(angle)), centre_cm=where.tolist())
    return out.reshape(n, rows, cols), truth


def simulate_gestures(
    out_dir: PathType,
    seed: int = 0,
    people: int = 5,
    repetitions: int = 16,
    gestures: Sequence[str] = GESTURES,
    progress: bool = True,
) -> list[Path]:
    """Write a SYNTHETIC gesture set: ``people x gestures x repetitions`` ``.npz`` files.

    Parameters
    ----------
    out_dir : str or PathLike
        Folder to write (created if needed); files are ``p{person}_{gesture}_{rep:02d}.npz``
        with ``frames`` (150 x 20 x 20, kPa, float32), ``rate_hz`` (50), ``label``,
        ``person``, ``repetition``, ``gesture``, ``unit`` and JSON ``metadata`` (with
        ``"synthetic": true``) and ``truth`` (the generating parameters).
    seed : int, default 0
        Everything is determined by the seed; a person's habits do not depend on how
        many repetitions or gestures are asked for.
    people, repetitions : int, default 5, 16
    gestures : sequence of str, default all seven :data:`GESTURES`
    progress : bool, default True
        Show a progress bar (tqdm, on stderr).

    Returns
    -------
    list of Path
        The files written, in order.

    Examples
    --------
    >>> import tempfile
    >>> paths = simulate_gestures(tempfile.mkdtemp(), people=1, repetitions=1,
    ...                           gestures=["poke"], progress=False)
    >>> [p.name for p in paths]
    ['p0_poke_00.npz']
    """
    unknown = [g for g in gestures if g not in GESTURES]
    if unknown:
        raise ValueError(f"unknown gesture(s) {unknown}; choose from {list(GESTURES)}")
    if people < 1 or repetitions < 1:
        raise ValueError(f"people and repetitions must be >= 1, got {people}, {repetitions}")
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    jobs = [(i, g, r) for i in range(people) for g in gestures for r in range(repetitions)]
    if progress:
        from tqdm import tqdm

        jobs = tqdm(jobs, desc="simulating gestures", unit="gesture")
    persons: dict[int, dict] = {}
    paths = []
    for i, g, r in jobs:
        if i not in persons:
            persons[i] = _person(seed, i)
        rng = np.random.default_rng([seed, i, GESTURES.index(g), r])
        frames, truth = render_gesture(g, persons[i], rng)
        paths.append(_write_gesture(out / f"p{i}_{g}_{r:02d}.npz", frames, truth, seed,
                                    i, persons[i], g, r))
    return paths


def _write_gesture(path: Path, frames: np.ndarray, truth: dict, seed: int, i: int,
                   person: dict, gesture: str, r: int) -> Path:
    """Write one simulated gesture of person ``i``, repetition ``r``, to ``path`` (the fields
    of :func:`simulate_gestures`); the truth also holds the person's parameters (not the
    habits)."""
    meta = {
        "synthetic": True,
        "source": "frictionfit.simulation.gestures (SYNTHETIC, not measured)",
        "seed": seed,
        "sensor": "20x20 textile pressure matrix, 1 cm pitch, 50 frames/s",
        "label": gesture, "person": f"p{i}", "repetition": r, "gesture": gesture,
    }
    person_truth = {k: v for k, v in person.items() if k != "habits"}
    np.savez_compressed(
        path,
        frames=frames.astype(np.float32),
        rate_hz=np.float64(FRAME_RATE_HZ),
        label=gesture,
        person=f"p{i}",
        repetition=r,
        gesture=gesture,
        unit="kPa",
        metadata=json.dumps(meta),
        truth=json.dumps({**truth, "person": person_truth}),
    )
    return path
