"""Motor-torque excitations of the reference logs, drawn from a seeded ``numpy.random.Generator``.

Every design is a command per sample, held over the sample interval (the log convention: torque[k] acts over
[t_k, t_k+1)). Amplitudes are multiples of the drive's f_m (the sidecar's value). Each starts with 50 ms of rest
(the load sensor's noise and offset show before anything moves). Kinds (``KINDS``):

* ``default``: the product's documented default design, re-implemented from its description (README, the
  docstring of the product's synthetic-log module): a repeating block of a 1 ms pulse of +A (A cycling through
  1.6, 2.5, 4.0 f_m, one value per block), 0.25 s rest, a ramp 0 -> +1.15 f_m over 60 ms, held 40 ms, down to 0
  over 20 ms, 0.2 s rest, then the same with -A and -1.15.
* ``steps``: torque steps of 1.3-3 f_m (random sign) held 20-80 ms, each followed by 0.25 s at zero.
* ``pulse_train``: the paper's one-way impulse experiment: 1 ms pulses of one amplitude A in 1.05-1.5 f_m and one
  sign, every S in 20-100 ms (A, S and the sign drawn once per log).
* ``bidirectional``: 0.5-2 ms pulses of 1.5-5 f_m with random sign, each followed by 0.1-0.35 s of rest.
* ``pd_steps``: closed loop: the generator's own PD on the floor-quantized encoder at the log's rate
  (physics.md section 3: Kp* = 200 /rad, Kd* = 19.2, derivative of the measurement by backward difference,
  saturation 20 f_m), set-point steps of 2-300 counts (log-uniform, random sign) held 0.15-0.4 s; the log keeps
  what the controller sent.
* ``chirp``: A sin(phase(t)), a logarithmic sweep from 3-8 Hz to min(0.1 rate, 150-300 Hz), A in 1.2-2 f_m.
* ``mix``: a diagnosis-style random mix: 0.5-2 ms pulses of 1.3-5 f_m (random sign) followed by 0.1-0.35 s of
  rest, and (40 % of the time) slow trapezoidal moves of 1.05-1.6 f_m (20-60 ms ramps, 0.1-0.4 s plateau, random
  sign) that turn the motor by up to a few revolutions, then 0.25 s of rest.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

KINDS = ("default", "steps", "pulse_train", "bidirectional", "pd_steps", "chirp", "mix")
LEAD_IN_S = 0.05
PD_KP_STAR = 200.0          # physics.md section 3
PD_KD_STAR = 19.2
PD_SATURATION_STAR = 20.0


@dataclass(frozen=True)
class Excitation:
    """A drawn excitation: ``kind``, its drawn ``params`` (for the truth), and either an open-loop ``schedule``
    [N m per sample] or a closed-loop ``pd`` design."""

    kind: str
    params: dict
    schedule: np.ndarray | None = None
    pd: PDDesign | None = None

    def command(self) -> Callable[[int, float], float]:
        """A fresh ``command(k, q_m_true) -> torque`` for one simulation (a PD keeps state)."""
        if self.pd is not None:
            return self.pd.controller()
        schedule = self.schedule
        return lambda k, q_m: float(schedule[k])


@dataclass(frozen=True)
class PDDesign:
    """Sampled PD on the floor-quantized motor encoder (SI gains from physics.md's non-dimensional ones)."""

    f_m: float
    T_c: float
    dt: float
    count_rad: float
    steps_counts: np.ndarray          # set-point increment [counts] applied at each sample (mostly 0)
    gains: tuple[float, float] = field(default=(PD_KP_STAR, PD_KD_STAR))

    def controller(self) -> Callable[[int, float], float]:
        kp, kd = self.gains
        f_m, T_c, dt, c = self.f_m, self.T_c, self.dt, self.count_rad
        limit = PD_SATURATION_STAR * f_m
        state = {"y_prev": None, "setpoint": 0.0}
        steps = self.steps_counts

        def command(k: int, q_m: float) -> float:
            y = math.floor(q_m / c) * c
            if state["y_prev"] is None:
                state["y_prev"], state["setpoint"] = y, y
            state["setpoint"] += steps[k] * c
            u = f_m * (kp * (state["setpoint"] - y) - kd * T_c * (y - state["y_prev"]) / dt)
            state["y_prev"] = y
            return min(limit, max(-limit, u))
        return command


def draw(kind: str, rng: np.random.Generator, f_m: float, rate_hz: float, duration_s: float,
         T_c: float = math.sqrt(2e-5 / 0.01), count_rad: float = 2 * math.pi / 12566) -> Excitation:
    """Draw an excitation of ``kind`` for a log of ``duration_s`` at ``rate_hz`` (n = round(duration * rate)
    commanded intervals)."""
    n = round(duration_s * rate_hz)
    if kind == "pd_steps":
        return _pd_steps(rng, f_m, rate_hz, n, T_c, count_rad)
    makers = {"default": _default, "steps": _steps, "pulse_train": _pulse_train, "bidirectional": _bidirectional,
              "chirp": _chirp, "mix": _mix}
    if kind not in makers:
        raise ValueError(f"unknown excitation {kind!r}; known: {', '.join(KINDS)}")
    tau_star, params = makers[kind](rng, rate_hz, n)
    return Excitation(kind, params, tau_star[:n] * f_m)


class _Builder:
    """A torque* sequence written block by block on the sample grid (room beyond n, cut by ``draw``)."""

    def __init__(self, rate_hz: float, n: int) -> None:
        self.rate, self.n = rate_hz, n
        self.tau = np.zeros(n + int(2.0 * rate_hz) + 10)
        self.k = round(LEAD_IN_S * rate_hz)

    def samples(self, seconds: float) -> int:
        return max(1, round(seconds * self.rate))

    def hold(self, level: float, seconds: float) -> None:
        m = self.samples(seconds)
        self.tau[self.k:self.k + m] = level
        self.k += m

    def ramp(self, start: float, stop: float, seconds: float) -> None:
        m = self.samples(seconds)
        self.tau[self.k:self.k + m] = start + (stop - start) * np.arange(m) / m
        self.k += m

    @property
    def open(self) -> bool:
        return self.k < self.n


def _default(rng: np.random.Generator, rate: float, n: int) -> tuple[np.ndarray, dict]:
    b, block = _Builder(rate, n), 0
    amplitudes = (1.6, 2.5, 4.0)
    while b.open:
        a = amplitudes[block % 3]
        for sign in (1.0, -1.0):
            b.hold(sign * a, 1e-3)
            b.hold(0.0, 0.25)
            b.ramp(0.0, sign * 1.15, 0.06)
            b.hold(sign * 1.15, 0.04)
            b.ramp(sign * 1.15, 0.0, 0.02)
            b.hold(0.0, 0.2)
        block += 1
    return b.tau, {"amplitudes_star": list(amplitudes)}


def _steps(rng: np.random.Generator, rate: float, n: int) -> tuple[np.ndarray, dict]:
    b, count = _Builder(rate, n), 0
    while b.open:
        b.hold(rng.choice((-1.0, 1.0)) * rng.uniform(1.3, 3.0), rng.uniform(0.02, 0.08))
        b.hold(0.0, 0.25)
        count += 1
    return b.tau, {"n_steps": count, "level_star": [1.3, 3.0], "hold_s": [0.02, 0.08], "rest_s": 0.25}


def _pulse_train(rng: np.random.Generator, rate: float, n: int) -> tuple[np.ndarray, dict]:
    a, spacing, sign = rng.uniform(1.05, 1.5), rng.uniform(0.02, 0.1), rng.choice((-1.0, 1.0))
    b = _Builder(rate, n)
    width = b.samples(1e-3)
    step = b.samples(spacing)
    while b.open:
        b.tau[b.k:b.k + width] = sign * a
        b.k += step
    return b.tau, {"amplitude_star": float(sign * a), "spacing_s": step / rate, "width_s": width / rate}


def _bidirectional(rng: np.random.Generator, rate: float, n: int) -> tuple[np.ndarray, dict]:
    b = _Builder(rate, n)
    while b.open:
        b.hold(rng.choice((-1.0, 1.0)) * rng.uniform(1.5, 5.0), rng.uniform(0.5e-3, 2e-3))
        b.hold(0.0, rng.uniform(0.1, 0.35))
    return b.tau, {"amplitude_star": [1.5, 5.0], "width_s": [0.5e-3, 2e-3], "rest_s": [0.1, 0.35]}


def _chirp(rng: np.random.Generator, rate: float, n: int) -> tuple[np.ndarray, dict]:
    f0, f1 = rng.uniform(3.0, 8.0), min(0.1 * rate, rng.uniform(150.0, 300.0))
    a = rng.uniform(1.2, 2.0)
    b = _Builder(rate, n)
    m = n - b.k
    t = np.arange(m) / rate
    span = max(t[-1], 1e-9) if m else 1.0
    phase = 2 * math.pi * f0 * span / math.log(f1 / f0) * (np.exp(t / span * math.log(f1 / f0)) - 1.0)
    b.tau[b.k:n] = a * np.sin(phase)
    return b.tau, {"amplitude_star": a, "f0_hz": f0, "f1_hz": f1}


def _mix(rng: np.random.Generator, rate: float, n: int) -> tuple[np.ndarray, dict]:
    b, moves, pulses = _Builder(rate, n), 0, 0
    while b.open:
        sign = rng.choice((-1.0, 1.0))
        if rng.random() < 0.4:
            level, ramp, plateau = rng.uniform(1.05, 1.6), rng.uniform(0.02, 0.06), rng.uniform(0.1, 0.4)
            b.ramp(0.0, sign * level, ramp)
            b.hold(sign * level, plateau)
            b.ramp(sign * level, 0.0, ramp)
            b.hold(0.0, 0.25)
            moves += 1
        else:
            b.hold(sign * rng.uniform(1.3, 5.0), rng.uniform(0.5e-3, 2e-3))
            b.hold(0.0, rng.uniform(0.1, 0.35))
            pulses += 1
    return b.tau, {"moves": moves, "pulses": pulses}


def _pd_steps(rng: np.random.Generator, f_m: float, rate: float, n: int, T_c: float,
              count_rad: float) -> Excitation:
    steps = np.zeros(n + 1)
    k = round(LEAD_IN_S * rate)
    sizes, at = [], []
    while k < n:
        size = round(math.exp(rng.uniform(math.log(2), math.log(300)))) * int(rng.choice((-1, 1)))
        steps[k] = size
        sizes.append(size)
        at.append(k)
        k += round(rng.uniform(0.15, 0.4) * rate)
    design = PDDesign(f_m, T_c, 1.0 / rate, count_rad, steps)
    return Excitation("pd_steps", {"kp_star": PD_KP_STAR, "kd_star": PD_KD_STAR, "saturation_star":
                                   PD_SATURATION_STAR, "setpoint_steps_counts": sizes, "setpoint_step_samples": at},
                      None, design)
