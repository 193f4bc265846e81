"""Synthetic "measured" logs from the plant FMU, for testing identification against known parameters.

The documented default excitation (``default_excitation``) is a repeating block, in non-dimensional torque
tau* = T/f_m, sampled at the log's rate and held between samples:

1. a 1 ms pulse of tau* = +A (A cycling through 1.6, 2.5, 4.0), then 0.25 s of rest;
2. a slow ramp from 0 to tau* = +1.15 over 60 ms, held 40 ms (the motor slides for tens of ms while the load rings
   on it: this is what separates K_s from J_l), then back to 0 over 20 ms; 0.2 s of rest;
3. the same pulse and ramp with negative sign.

Measurements: the motor encoder is floor-quantized (``encoder_counts_per_rev``), the load sensor sees the arm angle
plus white noise of ``load_noise_m`` at the arm tip (2 nm default) and an arbitrary zero offset.
"""
from __future__ import annotations

import numpy as np

from ..model.params import DriveParams
from ..model.pool import pooled_plant
from .logs import DriveLog, LogMeta


def default_excitation(params: DriveParams, duration_s: float = 10.0, rate_hz: float = 5000.0) -> np.ndarray:
    """Motor torque [N m] per sample (held over each sample interval) for ``duration_s`` seconds."""
    dt = 1.0 / rate_hz
    n = int(round(duration_s * rate_hz))
    tau = np.zeros(n + int(round(0.7 * rate_hz)))  # room for the last block, cut below

    def seg(t0: float, t1: float) -> slice:
        return slice(int(round(t0 / dt)), int(round(t1 / dt)))

    t, k = 0.05, 0
    amplitudes = (1.6, 2.5, 4.0)
    while t < duration_s:
        sign = 1.0 if k % 2 == 0 else -1.0
        a = amplitudes[(k // 2) % len(amplitudes)]
        tau[seg(t, t + 1e-3)] = sign * a
        t += 1e-3 + 0.25
        i = seg(t, t + 0.06)
        tau[i] = sign * np.linspace(0, 1.15, i.stop - i.start, endpoint=False)
        tau[seg(t + 0.06, t + 0.10)] = sign * 1.15
        i = seg(t + 0.10, t + 0.12)
        tau[i] = sign * np.linspace(1.15, 0, i.stop - i.start, endpoint=False)
        t += 0.12 + 0.2
        k += 1
    return tau[:n] * params.f_m


def synthetic_log(params: DriveParams, torque: np.ndarray | None = None, *, duration_s: float = 10.0,
                  rate_hz: float = 5000.0, load_noise_m: float = 2e-9, load_offset_rad: float = 0.0,
                  seed: int = 0, fmi_version: int = 2) -> DriveLog:
    """Simulate ``torque`` (default: ``default_excitation``) through the FMU and measure it like a real drive."""
    if torque is None:
        torque = default_excitation(params, duration_s, rate_hz)
    torque = np.asarray(torque, dtype=float)
    with pooled_plant(params, fmi_version) as plant:
        q_m, q_l = plant.positions(torque, 1.0 / rate_hz)
    return _measured(params, torque, q_m, q_l, rate_hz, load_noise_m, load_offset_rad, seed, "synthetic")


def _measured(params: DriveParams, torque: np.ndarray, q_m: np.ndarray, q_l: np.ndarray, rate_hz: float,
              load_noise_m: float, load_offset_rad: float, seed: int, source: str) -> DriveLog:
    """The log a drive's sensors record of the true angles: floor-quantized encoder, noisy offset load sensor."""
    rng = np.random.default_rng(seed)
    count = params.count_rad
    motor = np.floor(q_m / count) * count
    load = q_l + load_offset_rad + rng.normal(0.0, load_noise_m / params.arm_length, q_l.size)
    applied = np.append(torque, 0.0)  # the torque logged at sample k is the one held after it
    meta = LogMeta(r=params.r, J_m_kgm2=params.J_m, f_m_Nm=params.f_m, arm_length_m=params.arm_length,
                   encoder_counts_per_rev=params.encoder_counts_per_rev, sample_rate_hz=rate_hz)
    return DriveLog(np.arange(q_m.size) / rate_hz, applied, motor, load, meta, source=source)


def diagnosis_excitation(params: DriveParams, duration_s: float = 10.0, rate_hz: float = 5000.0,
                         seed: int = 1) -> np.ndarray:
    """Motor torque [N m] per sample for testing the discrepancy workflow: a seeded random sequence, unlike the
    identifier's fixed default (``default_excitation``), of the kind an engineer logs on a real joint:

    - pulses of random width (0.5-2 ms) and amplitude (tau* 1.3-5, random sign), each followed by 0.1-0.35 s of
      rest (the load rings and stops);
    - slow trapezoidal moves (tau* 1.05-1.6, 0.1-0.4 s plateau, 20-60 ms ramps, random sign) that turn the motor
      by up to a few revolutions (kinematic error, Stribeck and viscous friction show in these), then 0.25 s rest.

    Moves and pulses alternate at random (40 % moves); the signs are drawn so the axis wanders both ways.
    """
    rng = np.random.default_rng(seed)
    dt = 1.0 / rate_hz
    n = int(round(duration_s * rate_hz))
    tau = np.zeros(n + int(round(1.5 * rate_hz)))
    k = int(round(0.05 / dt))
    while k < n:
        sign = rng.choice((-1.0, 1.0))
        if rng.random() < 0.4:
            level = rng.uniform(1.05, 1.6)
            ramp, hold = int(rng.uniform(0.02, 0.06) / dt), int(rng.uniform(0.1, 0.4) / dt)
            tau[k:k + ramp] = sign * level * np.arange(ramp) / ramp
            tau[k + ramp:k + ramp + hold] = sign * level
            tau[k + ramp + hold:k + 2 * ramp + hold] = sign * level * (1 - np.arange(ramp) / ramp)
            k += 2 * ramp + hold + int(0.25 / dt)
        else:
            width = max(1, int(round(rng.uniform(0.5e-3, 2e-3) / dt)))
            tau[k:k + width] = sign * rng.uniform(1.3, 5.0)
            k += width + int(rng.uniform(0.1, 0.35) / dt)
    return tau[:n] * params.f_m


# Logs with one (or two) effects of the library hidden at a realistic magnitude on the nominal drive, for testing
# the discrepancy workflow: name -> (hidden FMU parameters, the parameter holding the effect's magnitude, the
# effects a diagnosis must name). Why realistic: b_m 1e-4 N m s/rad is 5 % of f_m at 5 rad/s; b_l 1 N m s/rad is
# 2 % damping of the load's ringing; Stribeck static/Coulomb 1.5 with v_s = 1e-4 rad/s (a few µm/s at the teeth);
# asymmetry 15 %; hardening 3e6 /rad^2 stiffens the spring ~10 % at the 1e-4 rad a pulse winds; hysteresis torque
# equal to the load friction; kinematic error 1e-5 rad (2 arcsec) at twice the wave-generator frequency.
HIDDEN_EFFECT_CASES: dict[str, tuple[dict[str, float], str | None, list[str]]] = {
    "viscous_motor": ({"b_m": 1e-4}, "b_m", ["viscous_motor"]),
    "viscous_load": ({"b_l": 1.0}, "b_l", ["viscous_load"]),
    "stribeck": ({"stribeck_ratio": 0.5, "stribeck_velocity": 1e-4}, "stribeck_ratio", ["stribeck"]),
    "asymmetric_friction": ({"friction_asymmetry": 0.15}, "friction_asymmetry", ["asymmetric_friction"]),
    "hardening": ({"hardening": 3e6}, "hardening", ["hardening"]),
    "hysteresis": ({"hysteresis_torque": 1e-3, "hysteresis_stiffness": 1e4}, "hysteresis_torque", ["hysteresis"]),
    "kinematic_error": ({"kinematic_error": 1e-5, "kinematic_error_phase": 0.7}, "kinematic_error",
                        ["kinematic_error"]),
    "flexibility": ({}, "K_s", ["flexibility"]),  # the nominal (flexible) drive, diagnosed from the rigid model
    "clean": ({}, None, []),
    "viscous_load+hardening": ({"b_l": 1.0, "hardening": 3e6}, None, ["viscous_load", "hardening"]),
}


def hidden_effect_log(case: str, duration_s: float = 6.0, seed: int = 3) -> DriveLog:
    """A "measured" log of the nominal drive with the effects of ``HIDDEN_EFFECT_CASES[case]`` hidden in it."""
    hidden = HIDDEN_EFFECT_CASES[case][0]
    p = DriveParams().with_values(**hidden)
    tau = diagnosis_excitation(p, duration_s, 5000.0, seed=seed)
    return synthetic_log(p, tau, duration_s=duration_s, seed=seed + 2, load_offset_rad=1e-3)


# Logs with an effect that is NOT in the library (the workflow must say it cannot explain them, and where): name ->
# description. "amplifier_lag": the motor receives the logged torque command through the current loop's first-order
# lag (time constant 0.3 ms, a ~530 Hz bandwidth), which the logs of real drives often hide; a pulse of 0.5-2 ms
# is smeared out (same impulse, lower peak, later breakaway), slow moves are hardly touched.
OUT_OF_LIBRARY_CASES: dict[str, str] = {
    "amplifier_lag": "the motor torque lags the logged command (first order, 0.3 ms)",
}
AMPLIFIER_LAG_S = 3e-4


def out_of_library_log(case: str, duration_s: float = 4.0, seed: int = 3, substeps: int = 20) -> DriveLog:
    """A "measured" log of the nominal drive with ``OUT_OF_LIBRARY_CASES[case]`` hidden in it: the plant FMU is
    driven ``substeps`` times per log sample by the lagged torque (exact first-order response of the held command
    on the fine grid), then sampled and measured as ``synthetic_log`` does; the log keeps the command."""
    if case not in OUT_OF_LIBRARY_CASES:
        raise ValueError(f"unknown case {case!r}; known: {', '.join(OUT_OF_LIBRARY_CASES)}")
    p = DriveParams()
    rate = 5000.0
    command = diagnosis_excitation(p, duration_s, rate, seed=seed)
    fine = np.repeat(command, substeps)
    h = 1.0 / (rate * substeps)
    a = float(np.exp(-h / AMPLIFIER_LAG_S))
    applied = np.empty_like(fine)
    y = 0.0
    for k, u in enumerate(fine):  # the fine step's mean of the exact response, so that the impulse is kept
        y_next = u + (y - u) * a
        applied[k] = u + (y - u) * (1 - a) * AMPLIFIER_LAG_S / h
        y = y_next
    with pooled_plant(p) as plant:
        q_m, q_l = plant.positions(applied, h)
    return _measured(p, command, q_m[::substeps], q_l[::substeps], rate, 2e-9, 1e-3, seed + 2,
                     f"synthetic ({case})")
