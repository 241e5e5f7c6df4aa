"""Whole rubbing measurements with known truth, shaped like the lab's recordings.

A measurement: the fingers hold a textile, the index finger runs 5 motions (``move p2``
at 0.05 + 2k s, ``move p1`` at 1.05 + 2k s), 10.05 s at 1 kHz, channels ``thumb_x``,
``thumb_y``, ``index_x``, ``index_y`` in N, written as ``s{session}_{label}_{trial:02d}``.

The tangential force is the contact law of :mod:`frictionfit.models` (``rich``: static
peak, slip weakening, two Maxwell branches, damping), driven continuously from one second
before the first command (the fingers closing) to the end, so every motion starts from
the state the previous ones left. Each motion has its own material parameters, taking over
:data:`SWITCH_S` after its out command, halfway through the stroke, as the finger slides
onto a new patch of the textile; the contact's elastic and relaxing forces carry over
(its displacements rescaled by the change of stiffness), so only the friction limit
changes there, by the motion-to-motion change of the material (a few per cent).
Effects the fitted family does not model:

- motor: trapezoid velocity profile (acceleration phases of 8-15 ms) with a latency,
  stroke and duration that drift per session and jitter per movement;
- a viscous sliding drag proportional to the finger velocity;
- channels: thumb ~ -gain x index, lateral (y) components, cross-talk, the index
  sensor turning with the finger, leakage of the normal force with finger position;
- sensor offsets per session with a slow linear + random-walk drift, AR(1) noise
  (1.5-4 mN), 50 Hz pickup on some sessions, ADC quantisation of 1 or 2 mN;
- transmission faults in about 1 motion in 6: dropped rows, NaN bursts, stuck values,
  spikes of up to tens of newtons.

Each measurement is made on a rig (:mod:`~frictionfit.simulation.rigs`: stroke, motor
speed, the finger's compliance, play and creep, sensor gains, the DAQ's low-pass and rate);
the default rig adds none of these.

On request the motor's position is read as ``frictionfit rub`` reads it (a few ms of read
latency, whole counts), into the sidecar's ``motor_positions``.

The force of every motion of every measurement comes from one batched (vmapped)
JAX call. All randomness comes from ``numpy`` generators keyed on
``(seed, session, class, trial)``, so a measurement does not depend on which other
classes are simulated with it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import asdict
from functools import lru_cache
from pathlib import Path

import numpy as np
from scipy.signal import lfilter

from frictionfit._types import PathType
from frictionfit.recording import (
    MOTOR_COLUMNS,
    MOTOR_POSITIONS,
    Channel,
    Event,
    Recording,
    write_recording,
)
from frictionfit.simulation.materials import (
    CLASSES,
    SESSION_SPREAD,
    draw_parameters,
    material_for,
)
from frictionfit.simulation.rigs import DEFAULT, SimulatedRig

__all__ = ["CHANNELS", "FAULT_KINDS", "measurement_truth", "simulate_dataset",
           "simulate_measurements"]

RATE_HZ = 1000.0
N_MOTIONS = 5
PERIOD_S = 2.0
T_OUT, T_BACK = 0.05, 1.05
N_SAMPLES = 10050
CHANNELS = ("thumb_x", "thumb_y", "index_x", "index_y")
FAULT_KINDS = ("drop", "nan", "stuck", "spike")
FAULT_RATE = 1.0 / 6.0
#: The simulated history starts this long before t = 0 (s): the fingers closing.
HISTORY_S = 1.0
#: A motion's material parameters take over this long after its out command (s): the
#: finger is sliding then for every drawn latency and duration.
SWITCH_S = 0.08
_LAW = ("k", "f_kin", "f_static_excess", "slip_length", "relax_frac", "tau",
        "relax_frac2", "tau2", "damping")
_FORCE_SCALED = ("k", "f_kin", "f_static_excess", "damping", "drag")
#: The actuator's positions (counts) at ``p1`` and ``p2`` when its positions are read.
P1_COUNTS, P2_COUNTS = 2048, 2304


def motor_profile(t: np.ndarray, start: float, duration: float, accel: float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Trapezoid-velocity move from 0 to 1: position and velocity (1/s) at times ``t`` (s).

    The motor starts at ``start`` s, accelerates for ``accel`` s, cruises, decelerates
    for ``accel`` s and stops at ``start + duration``.
    """
    tau = np.clip(t - start, 0.0, duration)
    v_max = 1.0 / (duration - accel)
    a = v_max / accel
    rise = 0.5 * a * np.minimum(tau, accel) ** 2
    cruise = v_max * np.clip(tau - accel, 0.0, duration - 2 * accel)
    tail = np.clip(tau - (duration - accel), 0.0, accel)
    fall = v_max * tail - 0.5 * a * tail**2
    vel = np.where((t > start) & (t < start + duration),
                   np.minimum(np.minimum(a * tau, v_max), a * (duration - tau)), 0.0)
    return rise + cruise + fall, vel


def _session(seed: int, session: int, rig: SimulatedRig = DEFAULT) -> dict:
    """Rig state of one day: motor, gains, offsets, noise; drawn from ``(seed, session)``,
    scaled by ``rig``."""
    rng = np.random.default_rng([seed, session, 0xD1A])
    day = {
        "session": session,
        "delay_s": rng.uniform(0.015, 0.035),
        "duration_s": rng.uniform(0.10, 0.15),
        "accel_s": rng.uniform(0.008, 0.015),
        "stroke_mm": rng.uniform(0.9, 1.1),
        "gains": [-rng.uniform(0.75, 1.1), rng.normal(0.0, 0.1),
                  float(np.exp(rng.normal(0.0, 0.05))), rng.normal(0.0, 0.12)],
        "crosstalk": rng.normal(0.0, 0.03),
        "rotation_rad": rng.uniform(0.02, 0.06),
        "leak_n": rng.normal(0.0, 0.03, 4).tolist(),
        "offsets_n": rng.normal(0.0, 0.6, 4).tolist(),
        "noise_sd_n": rng.uniform(0.0015, 0.004),
        "noise_ar1": rng.uniform(0.5, 0.85),
        "hum_n": float(rng.uniform(0.001, 0.005)) if rng.random() < 0.5 else 0.0,
        "quantum_n": float(rng.choice([0.001, 0.002])),
    }
    if rig == DEFAULT:  # bit for bit the simulator without rigs
        return day
    day["duration_s"] /= rig.motor_speed
    day["stroke_mm"] *= rig.stroke_mm or 1.0
    day["gains"] = [g * rig.gain_scale for g in day["gains"]]
    day["noise_sd_n"] *= rig.noise_scale
    day["hum_n"] *= rig.noise_scale
    return day | {"rig": rig}


def _plan(seed: int, session: dict, label: str, trial: int) -> dict:
    """Everything random about one measurement, drawn before any force is computed."""
    cls = CLASSES.index(label)
    state = np.random.default_rng([seed, session["session"], cls, 0x5E5])
    factor = {k: float(np.exp(sd * state.standard_normal())) for k, sd in SESSION_SPREAD.items()}
    rng = np.random.default_rng([seed, session["session"], cls, trial])
    base = draw_parameters(material_for(label), rng, factor)
    motions = []
    for i in range(N_MOTIONS):
        p = dict(base)
        for name in ("k", "f_kin", "f_static_excess", "tau"):
            p[name] *= float(np.exp(0.02 * rng.standard_normal()))
        p["f_kin"] *= 1.0 - 0.01 * i  # slow wear within the measurement
        moves = []
        for t_cmd in (PERIOD_S * i + T_OUT, PERIOD_S * i + T_BACK):
            delay = max(0.005, session["delay_s"] + 0.002 * rng.standard_normal())
            dur = session["duration_s"] * float(np.exp(0.02 * rng.standard_normal()))
            moves.append((t_cmd + delay, dur))
        motions.append({"params": p, "moves": moves})
    faults = []
    for i in range(N_MOTIONS):
        if rng.random() < FAULT_RATE:
            faults.append(_draw_fault(rng, i))
    return {"label": label, "trial": trial, "session": session, "base": base,
            "preload": float(rng.uniform(-0.3, 1.0)), "motions": motions, "faults": faults,
            "offset_jitter": rng.normal(0.0, 0.05, 4), "drift_slope": rng.normal(0.0, 0.002, 4),
            "rng": rng}


def _draw_fault(rng: np.random.Generator, motion: int) -> dict:
    kind = str(rng.choice(FAULT_KINDS))
    length = {"drop": (5, 250), "nan": (5, 100), "stuck": (20, 300), "spike": (1, 5)}[kind]
    n = int(rng.integers(*length))
    start = int(PERIOD_S * RATE_HZ * motion + rng.integers(0, int(PERIOD_S * RATE_HZ) - n))
    channels = list(CHANNELS)
    if kind in ("nan", "spike") and rng.random() < 0.5:
        channels = sorted(rng.choice(CHANNELS, int(rng.integers(1, 4)), replace=False).tolist())
    return {"motion": motion, "kind": kind, "start": start, "n": n, "channels": channels}


def _drive(plan: dict) -> tuple[np.ndarray, np.ndarray]:
    """Finger position (mm) and velocity (mm/s) from ``-HISTORY_S`` to the end, 1 kHz."""
    s = plan["session"]
    t = np.arange(_N_HISTORY + N_SAMPLES) / RATE_HZ - HISTORY_S
    stroke, accel = s["stroke_mm"], s["accel_s"]
    # closing the fingers leaves an uncontrolled internal force
    x0, v0 = motor_profile(t, T_OUT - 0.95, s["duration_s"], accel)
    amp = plan["preload"] * stroke
    progress, rate = _progress(plan, t)
    x, v = amp * (1 - x0) + stroke * progress, -amp * v0 + stroke * rate
    play = s["rig"].play_mm if "rig" in s else 0.0
    return (x, v) if play == 0.0 else _with_play(x, play)


def _with_play(x: np.ndarray, play: float) -> tuple[np.ndarray, np.ndarray]:
    """The finger's position and velocity behind a dead band of width ``play`` (mm): it
    moves only where the motor's position ``x`` pushes it from one side of the band."""
    y = np.empty_like(x)
    y[0] = x[0]
    half = 0.5 * play
    for i in range(1, x.size):
        y[i] = min(max(y[i - 1], x[i] - half), x[i] + half)
    return y, np.gradient(y) * RATE_HZ


def _progress(plan: dict, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The motor's progress from ``p1`` (0) to ``p2`` (1) over every motion, and its rate
    (1/s), at times ``t`` (s)."""
    accel = plan["session"]["accel_s"]
    progress, rate = np.zeros(t.shape), np.zeros(t.shape)
    for m in plan["motions"]:
        for sign, (start, duration) in zip((1.0, -1.0), m["moves"], strict=True):
            x, v = motor_profile(t, start, duration, accel)
            progress, rate = progress + sign * x, rate + sign * v
    return progress, rate


_N_HISTORY = round(HISTORY_S * RATE_HZ)
#: Sample (from ``-HISTORY_S``) where each motion's parameters take over, and the end.
_EDGES = (0, *(round((PERIOD_S * i + T_OUT + SWITCH_S + HISTORY_S) * RATE_HZ)
               for i in range(1, N_MOTIONS)), _N_HISTORY + N_SAMPLES)
#: The motion whose material each sample (from ``-HISTORY_S``) has.
_MOTION_OF = np.repeat(np.arange(N_MOTIONS), np.diff(_EDGES))


@lru_cache(maxsize=1)
def _batched_law():
    import jax

    from frictionfit.models import contact_force

    def piece(x, state, *params):
        return contact_force(x, 1.0 / RATE_HZ, *params, state=state, return_state=True)

    return jax.jit(jax.vmap(piece))


def _forces(x: np.ndarray, params: list[dict[str, np.ndarray]], pad_to: int) -> np.ndarray:
    """Contact force (N) of every measurement, ``x`` (B, n) in mm from ``-HISTORY_S``;
    ``params[i]``: motion ``i``'s law parameters, one per measurement. The law runs piece by
    piece (one jitted, vmapped call per motion), each from the state the last left, its
    displacements rescaled so that the forces carry over.

    The batch is padded (repeating its last row) to a multiple of ``pad_to`` so that
    batches of different sizes share one compilation.
    """
    n = x.shape[0]
    idx = np.minimum(np.arange(-(-n // pad_to) * pad_to), n - 1)
    state = None  # at rest
    pieces = []
    for i, (a, b) in enumerate(zip(_EDGES[:-1], _EDGES[1:], strict=True)):
        if state is not None:  # the same elastic and relaxing forces under the new stiffness
            r = params[i - 1]["k"][idx] / params[i]["k"][idx]
            z, slip, ws, *rest = state
            state = (z * r, slip, tuple(w * r for w in ws), *rest)
        force, state = _batched_law()(x[idx, a:b], state,
                                      *(params[i][name][idx] for name in _LAW))
        pieces.append(np.asarray(force)[:n])
    return np.concatenate(pieces, axis=1)


def _rig_forces(x: np.ndarray, params: list[dict[str, np.ndarray]], pad_to: int,
                rig: SimulatedRig) -> np.ndarray:
    """:func:`_forces` through the rig's finger: its stiffness in series with the contact's
    and its creep under the force (one correction pass), as :mod:`~.rigs` describes."""
    if rig.finger_k is not None:
        params = [p | {"k": p["k"] * rig.finger_k / (p["k"] + rig.finger_k)} for p in params]
    force = _forces(x, params, pad_to)
    if rig.creep_mm_per_n == 0.0:
        return force
    a = np.exp(-1.0 / (RATE_HZ * rig.creep_tau_s))  # Kelvin-Voigt creep, exact per step
    creep = lfilter([rig.creep_mm_per_n * (1.0 - a)], [1.0, -a], force, axis=1)
    return _forces(x - creep, params, pad_to)


def _channel_gains(s: dict) -> np.ndarray:
    g_tx, g_ty, g_ix, g_iy = s["gains"]
    return np.array([g_tx, g_ty + s["crosstalk"] * g_tx, g_ix, g_iy])


def _channels(plan: dict, force: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Noise-free channel signals (n, 4) in N from the force and finger position."""
    s = plan["session"]
    g_tx, g_ty, g_ix, g_iy = s["gains"]
    pos = x / s["stroke_mm"]
    theta = s["rotation_rad"] * pos
    thumb_x = g_tx * force
    out = np.stack([thumb_x, g_ty * force + s["crosstalk"] * thumb_x,
                    g_ix * force * np.cos(theta), (g_iy + g_ix * np.sin(theta)) * force], axis=1)
    return out + pos[:, None] * np.asarray(s["leak_n"])


def _sensor(plan: dict, clean: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Offsets, drift, AR(1) noise, 50 Hz pickup and quantisation on top of ``clean`` (n, 4).

    Returns the sensor's signals and their noise-free level (clean + offsets + drift), N.
    """
    s, rng = plan["session"], plan["rng"]
    t = np.arange(clean.shape[0]) / RATE_HZ
    offsets = np.asarray(s["offsets_n"]) + plan["offset_jitter"]
    walk = np.cumsum(rng.normal(0.0, 5e-5, clean.shape), axis=0)
    white = rng.standard_normal(clean.shape) * s["noise_sd_n"] * np.sqrt(1 - s["noise_ar1"] ** 2)
    noise = lfilter([1.0], [1.0, -s["noise_ar1"]], white, axis=0)
    hum = s["hum_n"] * rng.uniform(0.3, 1.0, 4) * np.sin(
        2 * np.pi * 50.0 * t[:, None] + rng.uniform(0, 2 * np.pi, 4))
    level = clean + offsets + plan["drift_slope"] * t[:, None] + walk
    lowpass = s["rig"].lowpass_hz if "rig" in s else None
    if lowpass is not None:  # the DAQ's filter, causal, on what the sensor gives it
        from scipy.signal import butter

        b, a = butter(2, lowpass / (RATE_HZ / 2))
        noise, hum = lfilter(b, a, noise + hum, axis=0), 0.0
        level = lfilter(b, a, level - level[0], axis=0) + level[0]
    step = round(s["quantum_n"] * 1000)  # mN per ADC count
    # exact multiples of 1 mN, so the 3-decimal CSV reads back to the same floats
    return np.round((level + noise + hum) * 1000 / step) * step / 1000, level


def _apply_faults(plan: dict, t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    rng = plan["rng"]
    keep = np.ones(t.size, dtype=bool)
    for f in plan["faults"]:
        a, b = f["start"], f["start"] + f["n"]
        cols = [CHANNELS.index(c) for c in f["channels"]]
        if f["kind"] == "drop":
            keep[a:b] = False
        elif f["kind"] == "nan":
            y[a:b, cols] = np.nan
        elif f["kind"] == "stuck":
            y[a:b] = y[a]
        else:
            for _ in range(f["n"]):
                j = min(int(rng.integers(a, a + 200)), y.shape[0] - 1)
                y[j, cols] = np.round(y[j, cols] + rng.choice([-1, 1]) * rng.uniform(2, 40), 3)
    return t[keep], y[keep]


def _truth(plan: dict, level: np.ndarray, seed: int) -> dict:
    s = plan["session"]
    gains = _channel_gains(s)
    motions = []
    for i, m in enumerate(plan["motions"]):
        cmd = int(round((PERIOD_S * i + T_OUT) * RATE_HZ))
        per_channel = {}
        for j, name in enumerate(CHANNELS):
            g = abs(gains[j])
            eff = {n: float(v * (g if n in _FORCE_SCALED else 1.0)) for n, v in m["params"].items()}
            eff["k"] *= s["stroke_mm"]  # per nominal mm of the fitted drive
            eff["slip_length"] /= s["stroke_mm"]
            per_channel[name] = {"direction": float(np.sign(gains[j])), "gain": float(gains[j]),
                                 "baseline": float(level[cmd, j]), **eff}
        (o_s, o_d), (b_s, b_d) = m["moves"]
        motions.append({"index": i, "move_out": [o_s, o_s + o_d], "move_back": [b_s, b_s + b_d],
                        "delay": o_s - PERIOD_S * i - T_OUT, "ramp": o_d,
                        "params": m["params"], "channels": per_channel})
    faults = [{"motion": f["motion"], "kind": f["kind"], "channels": f["channels"],
               "t_start": f["start"] / RATE_HZ, "t_stop": (f["start"] + f["n"]) / RATE_HZ}
              for f in plan["faults"]]
    session = {k: v for k, v in s.items() if k not in ("session", "rig")}
    rig = {"rig": asdict(s["rig"])} if "rig" in s else {}
    return rig | {"generator": "frictionfit.simulation.measurements", "seed": seed,
            "law": "rich + viscous drag", "session": session, "preload": plan["preload"],
            "motions": motions, "faults": faults}


def measurement_truth(rec: Recording, name: str, channel: str = "index_x") -> float:
    """The value of ``name`` that a whole fit of ``rec``'s ``channel`` estimates, from the
    truth in its sidecar: the median over the fitted motions (all but the first); for
    ``f_kin`` the level halfway through the measurement's travel (where the fits' ``f_kin``
    is defined; their ``wear`` takes the trend) of the log-linear trend through the fitted
    motions' levels; ``ramp`` the movement duration (s); ``drag`` scaled by the channel's
    gain (N s/mm)."""
    motions = rec.truth["motions"]
    fitted = motions[1:]
    if name == "ramp":
        return float(np.median([m["ramp"] for m in fitted]))
    if name == "drag":
        return float(np.median([m["params"]["drag"] * abs(m["channels"][channel]["gain"])
                                for m in fitted]))
    levels = np.array([m["channels"][channel][name] for m in fitted])
    if name != "f_kin":
        return float(np.median(levels))
    index = np.array([m["index"] for m in fitted], dtype=np.float64)
    slope, at_zero = np.polyfit(index, np.log(levels), 1)
    # a motion's level holds from halfway through its out stroke (SWITCH_S) to halfway
    # through the next one: the middle of the travel, the end of the middle motion's out
    # stroke, lies a quarter motion before the middle of that motion's level
    return float(np.exp(at_zero + slope * ((len(motions) - 1) / 2 - 0.25)))


def _motor_positions(plan: dict, seed: int, rate_hz: float) -> dict:
    """The sidecar's ``motor_positions``: the motor's profile read every ``1/rate_hz`` s
    (each request up to 0.5 ms late, the position taken 0.2-0.8 ms after it, the reply
    1-2 ms after it), in whole counts from :data:`P1_COUNTS` to :data:`P2_COUNTS`."""
    rng = np.random.default_rng([seed, plan["session"]["session"], CLASSES.index(plan["label"]),
                                 plan["trial"], 0x905])
    n = int(N_SAMPLES / RATE_HZ * rate_hz)
    t_request = np.arange(n) / rate_hz + rng.uniform(0.0, 5e-4, n)
    t_read = t_request + rng.uniform(2e-4, 8e-4, n)
    t_reply = t_request + rng.uniform(1e-3, 2e-3, n)
    counts = np.round(P1_COUNTS + (P2_COUNTS - P1_COUNTS) * _progress(plan, t_read)[0])
    return {"columns": [dict(c) for c in MOTOR_COLUMNS],
            "reads": np.column_stack([t_request.round(6), t_reply.round(6), counts]).tolist(),
            "rate_hz_requested": rate_hz, "reads_failed": 0, "counts_per_revolution": 4096}


def simulate_measurements(specs: Sequence[tuple[int, str, int]], seed: int = 0, *,
                          pad_to: int = 35, position_rate_hz: float = 0.0,
                          rig: SimulatedRig = DEFAULT) -> list[Recording]:
    """Simulate measurements given as ``(session, label, trial)``; forces in one batch.

    Parameters
    ----------
    specs : sequence of (int, str, int)
        Session number, class label (see :data:`~frictionfit.simulation.materials.CLASSES`)
        and trial number of each measurement.
    seed : int
        Master seed; each measurement depends only on it and its own spec.
    pad_to : int
        Measurements per compiled batch shape (padding; does not change the result).
    position_rate_hz : float
        Also read the motor's position this often (Hz; 0: not at all, as in the lab's
        recordings), as ``frictionfit rub`` does; the reads do not change the forces.
    rig : SimulatedRig
        The rig (:data:`~frictionfit.simulation.rigs.RIGS`); default: no rig effect.

    Returns
    -------
    list of Recording
        In the order of ``specs``, named ``s{session}_{label}_{trial:02d}``, with the
        generating parameters, movement times (s) and faults in ``truth``.

    Examples
    --------
    >>> rec, = simulate_measurements([(1, "paper-2", 1)], seed=3)
    >>> rec.name, rec.channel_names, rec.samples.shape[1]
    ('s1_paper-2_01', ('thumb_x', 'thumb_y', 'index_x', 'index_y'), 4)
    """
    sessions: dict[int, dict] = {}
    plans = []
    for session, label, trial in specs:
        if session not in sessions:
            sessions[session] = _session(seed, session, rig)
        plans.append(_plan(seed, sessions[session], label, trial))
    x, v = (np.stack(a) for a in zip(*(_drive(p) for p in plans), strict=True))
    params = [{n: np.array([p["motions"][i]["params"][n] for p in plans]) for n in (*_LAW, "drag")}
              for i in range(N_MOTIONS)]
    drag = np.stack([p["drag"] for p in params])[_MOTION_OF].T  # (B, n): each piece's
    force = (_rig_forces(x, params, pad_to, rig) + drag * v)[:, _N_HISTORY:]
    x = x[:, _N_HISTORY:]
    recs = []
    for k, plan in enumerate(plans):
        clean = _channels(plan, force[k], x[k])
        measured, level = _sensor(plan, clean)
        t, y = _apply_faults(plan, np.arange(N_SAMPLES) / RATE_HZ, measured)
        material = material_for(plan["label"])
        read = position_rate_hz > 0
        events = [Event(PERIOD_S * i + dt, "move", tgt,
                        {"position": P2_COUNTS if tgt == "p2" else P1_COUNTS} if read else {})
                  for i in range(N_MOTIONS) for dt, tgt in ((T_OUT, "p2"), (T_BACK, "p1"))]
        metadata = {"label": plan["label"], "material": material.slug, "layers": material.layers,
                    "session": plan["session"]["session"], "trial": plan["trial"],
                    "rig": "frictionfit-simulator", "synthetic": True}
        if rig.decimation > 1:  # the DAQ's rate: every n-th sample of the simulator's
            kept = np.round(t * RATE_HZ).astype(int) % rig.decimation == 0
            t, y = t[kept], y[kept]
        if rig != DEFAULT:
            metadata["rig"] = rig.name
            if rig.stroke_mm is not None:
                metadata["stroke_mm"] = rig.stroke_mm
        recs.append(Recording(
            t, y, rig.rate_hz, tuple(Channel(c, "N") for c in CHANNELS),
            events=events, metadata=metadata, truth=_truth(plan, level, seed),
            extra={MOTOR_POSITIONS: _motor_positions(plan, seed, position_rate_hz)} if read else {},
            name=f"s{plan['session']['session']}_{plan['label']}_{plan['trial']:02d}"))
    return recs


def simulate_dataset(
    out: PathType,
    seed: int = 0,
    sessions: int = 2,
    measurements_per_class: int = 2,
    classes: Sequence[str] | None = None,
    *,
    batch: int = 35,
    position_rate_hz: float = 0.0,
    progress: Callable[[int], None] | None = None,
    rig: SimulatedRig = DEFAULT,
) -> list[Path]:
    """Write ``sessions x classes x measurements_per_class`` measurements to ``out``.

    Parameters
    ----------
    out : str or PathLike
        Folder (created if needed); one ``<name>.csv`` + ``<name>.json`` per measurement,
        forces in N with 3 decimals (as the lab writes them).
    seed : int
        Master seed: the same seed gives the same bytes.
    sessions, measurements_per_class : int
        Sessions are numbered from 1, trials from 1 within each session and class.
    classes : sequence of str, optional
        A subset of the 35 class labels (default: all); a measurement's data do not
        depend on the subset.
    batch : int
        Measurements simulated per batched JAX call.
    position_rate_hz : float
        The motor's position reads per second (0: none); see :func:`simulate_measurements`.
    progress : callable, optional
        Called with the number of measurements written after each batch.
    rig : SimulatedRig
        The rig the measurements are made on (default: no rig effect).

    Returns
    -------
    list of Path
        The CSV files written.
    """
    labels = list(CLASSES if classes is None else classes)
    for label in labels:
        material_for(label)
    if sessions < 1 or measurements_per_class < 1:
        raise ValueError(f"sessions and measurements_per_class must be >= 1, "
                         f"got {sessions} and {measurements_per_class}")
    specs = [(s, label, trial) for s in range(1, sessions + 1) for label in labels
             for trial in range(1, measurements_per_class + 1)]
    paths = []
    for start in range(0, len(specs), batch):
        chunk = specs[start:start + batch]
        for rec in simulate_measurements(chunk, seed, pad_to=batch,
                                         position_rate_hz=position_rate_hz, rig=rig):
            paths.append(write_recording(rec, Path(out) / rec.name, decimals=3))
        if progress is not None:
            progress(len(chunk))
    return paths
