"""The hidden effects the generator draws, with their shape variants, and how a magnitude is found for a class.

Each effect is a one-parameter family ``build(m) -> Effects``: the *magnitude* ``m`` scales the effect while its
shape (drawn once per case from the effect's own random stream) stays fixed. Variants real drives show, beyond the
product library's single shape:

==================== ================================ ===============================================================
effect               variants                          magnitude m (unit)
==================== ================================ ===============================================================
viscous_motor        --                                b_m [N m s/rad]
viscous_load         --                                b_l [N m s/rad]
stribeck             exponential, gaussian,            sliding excess at 0+, f (1 + m) (the static level is
                     separate_static                   f (1 + m (1 + 0.3..1)) for separate_static); v_s drawn
                                                       0.05-0.5x the load's typical slip speed (motor: v_s / r)
asymmetric_friction  --                                a_m = +-m, a_l = a_m x 0.5..1.5 (levels f (1 +- a))
hardening            cubic, three_slope                relative stiffening at the log's deflection scale d95:
                                                       cubic h = m / d95^2; three slopes K, (1+m) K, (1+k m) K,
                                                       k in 2..4, theta1 = 0.2..0.4 d95, theta2 = 1.5..2.5 theta1
hysteresis           dahl, maxwell                     total hysteresis torque [N m]; Dahl: H = m, saturation at
                                                       0.05..0.3 d95, exponent 1 / 1.5 / 2; Maxwell: 3-5 elements,
                                                       break deflections 0.03..0.5 d95, torques summing to m
kinematic_error      --                                2/rev amplitude [rad]; 4/rev = 0.15..0.6 of it; phases drawn
actuator_lag         --                                current-loop time constant [s] (outside the library)
friction_ripple      --                                relative ripple of the motor friction; 1, 2 or 4 per motor
                                                       revolution (outside the library)
==================== ================================ ===============================================================

d95 is the 95th percentile of |deflection| of the clean run of the same case, the slip speeds are medians over
the samples where a body slips: shapes are placed where the log can see them, as a real effect would be where the
drive operates.

**Magnitude classes.** weak = the magnitude at which the effect's own signal (the RMS over the log of the load
angle with the effect minus the load angle without it, same drive, excitation and start) is ``WEAK_SNR`` = 5 times
the load sensor's noise sigma; medium = weak x sqrt(10); strong = weak x 10 (a decade). ``weak_magnitude`` finds
it by a secant search in log-log coordinates: start at a prior magnitude, assume signal ~ m^p (p = 1 at first,
then the slope through the last two points, clipped to [0.25, 4]), stop when the signal is within 15 % of the
target or after 8 simulations, keep the closest. The achieved signal-to-noise ratio of every generated log is
measured again and recorded in its truth.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, fields, replace

import numpy as np

from .plant import (
    CubicStiffness,
    Dahl,
    Effects,
    FrictionRipple,
    KinematicError,
    MaxwellSlip,
    Stribeck,
    ThreeSlopeStiffness,
)

LIBRARY_EFFECTS = ("viscous_motor", "viscous_load", "stribeck", "asymmetric_friction", "hardening", "hysteresis",
                   "kinematic_error")
OUTSIDE_LIBRARY_EFFECTS = ("actuator_lag", "friction_ripple")
VARIANTS = {"stribeck": ("exponential", "gaussian", "separate_static"), "hardening": ("cubic", "three_slope"),
            "hysteresis": ("dahl", "maxwell")}
CLASSES = {"weak": 1.0, "medium": math.sqrt(10.0), "strong": 10.0}
WEAK_SNR = 5.0
SEARCH_TOLERANCE = 0.15
SEARCH_MAX_RUNS = 8


@dataclass(frozen=True)
class RunStats:
    """What the clean run of a case shows: deflection scale and typical slip speeds (for placing shapes)."""

    d95: float           # 95th percentile of |d| [rad]
    v_m: float           # median |v_m| while the motor slips [rad/s]
    v_l: float           # median |v_l| while the load slips [rad/s]
    sigma: float         # load sensor noise [rad]


@dataclass(frozen=True)
class EffectFamily:
    """One effect with its drawn shape: ``build(m)`` gives the Effects at magnitude m."""

    name: str
    variant: str
    unit: str
    prior: float
    cap: float
    build: Callable[[float], Effects]
    shape: dict


def draw_family(name: str, rng: np.random.Generator, stats: RunStats, drive_r: float, f_m: float, f_l: float,
                K_s: float, variant: str | None = None) -> EffectFamily:
    """The effect ``name`` with its shape drawn from ``rng`` (``variant`` forced when given)."""
    variants = VARIANTS.get(name, ("",))
    if variant is None:
        variant = variants[int(rng.integers(len(variants)))]
    if variant not in variants:
        raise ValueError(f"effect {name!r} has no variant {variant!r}; known: {', '.join(variants)}")
    makers = {"viscous_motor": _viscous_motor, "viscous_load": _viscous_load, "stribeck": _stribeck,
              "asymmetric_friction": _asymmetric, "hardening": _hardening, "hysteresis": _hysteresis,
              "kinematic_error": _kinematic, "actuator_lag": _lag, "friction_ripple": _ripple}
    if name not in makers:
        raise ValueError(f"unknown effect {name!r}; known: {', '.join(makers)}")
    ctx = {"rng": rng, "stats": stats, "r": drive_r, "f_m": f_m, "f_l": f_l, "K": K_s}
    return makers[name](variant, ctx)


def _viscous_motor(variant: str, c: dict) -> EffectFamily:
    prior = 0.05 * c["f_m"] / max(c["stats"].v_m, 1e-3)
    return EffectFamily("viscous_motor", variant, "N m s/rad", prior, math.inf, lambda m: Effects(b_m=m), {})


def _viscous_load(variant: str, c: dict) -> EffectFamily:
    prior = 0.05 * c["f_m"] / c["r"] / max(c["stats"].v_l, 1e-5)
    return EffectFamily("viscous_load", variant, "N m s/rad", prior, math.inf, lambda m: Effects(b_l=m), {})


def _stribeck(variant: str, c: dict) -> EffectFamily:
    rng = c["rng"]
    v_s = max(c["stats"].v_l, 1e-6) * math.exp(rng.uniform(math.log(0.05), math.log(0.5)))
    shape = variant if variant != "separate_static" else ("exponential", "gaussian")[int(rng.integers(2))]
    extra = rng.uniform(0.3, 1.0) if variant == "separate_static" else None
    detail = {"velocity_load_rad_s": v_s, "shape": shape, "static_over_sliding_excess": extra}

    def build(m: float) -> Effects:
        return Effects(stribeck=Stribeck(m, v_s, shape, None if extra is None else m * (1.0 + extra)))
    return EffectFamily("stribeck", variant, "1 (static/Coulomb - 1)", 0.1, 5.0, build, detail)


def _asymmetric(variant: str, c: dict) -> EffectFamily:
    rng = c["rng"]
    sign, ratio = float(rng.choice((-1.0, 1.0))), rng.uniform(0.5, 1.5)
    cap = 0.9 / max(1.0, ratio)
    return EffectFamily("asymmetric_friction", variant, "1", 0.03, cap,
                        lambda m: Effects(asymmetry_m=sign * m, asymmetry_l=sign * m * ratio),
                        {"sign": sign, "load_over_motor": ratio})


def _hardening(variant: str, c: dict) -> EffectFamily:
    rng, d95 = c["rng"], c["stats"].d95
    if variant == "cubic":
        return EffectFamily("hardening", variant, "1 (relative stiffening at d95)", 0.05, 20.0,
                            lambda m: Effects(stiffness=CubicStiffness(m / d95**2)), {"d95_rad": d95})
    t1 = d95 * rng.uniform(0.2, 0.4)
    t2 = t1 * rng.uniform(1.5, 2.5)
    k = rng.uniform(2.0, 4.0)
    return EffectFamily("hardening", variant, "1 (K2/K1 - 1)", 0.05, 20.0,
                        lambda m: Effects(stiffness=ThreeSlopeStiffness(t1, t2, 1.0 + m, 1.0 + k * m)),
                        {"theta1_rad": t1, "theta2_rad": t2, "k3_excess_over_k2_excess": k, "d95_rad": d95})


def _hysteresis(variant: str, c: dict) -> EffectFamily:
    rng, d95 = c["rng"], c["stats"].d95
    prior = 0.02 * c["K"] * d95
    if variant == "dahl":
        sat, n = d95 * rng.uniform(0.05, 0.3), float(rng.choice((1.0, 1.5, 2.0)))
        return EffectFamily("hysteresis", variant, "N m", prior, math.inf,
                            lambda m: Effects(hysteresis=Dahl(m, m / sat, n)),
                            {"saturation_deflection_rad": sat, "exponent": n})
    count = int(rng.integers(3, 6))
    breaks = d95 * np.exp(np.sort(rng.uniform(math.log(0.03), math.log(0.5), count)))
    weights = rng.uniform(0.5, 1.5, count)
    weights /= weights.sum()

    def build(m: float) -> Effects:
        torques = tuple(float(w * m) for w in weights)
        return Effects(hysteresis=MaxwellSlip(tuple(t / b for t, b in zip(torques, breaks)), torques))
    return EffectFamily("hysteresis", variant, "N m", prior, math.inf, build,
                        {"break_deflections_rad": breaks.tolist(), "weights": weights.tolist()})


def _kinematic(variant: str, c: dict) -> EffectFamily:
    rng = c["rng"]
    ratio, p2, p4 = rng.uniform(0.15, 0.6), rng.uniform(0, 2 * math.pi), rng.uniform(0, 2 * math.pi)
    return EffectFamily("kinematic_error", variant, "rad", 5.0 * c["stats"].sigma, 1e-3,
                        lambda m: Effects(kinematic_error=KinematicError(m, p2, ratio * m, p4)),
                        {"amp4_over_amp2": ratio, "phase2": p2, "phase4": p4})


def _lag(variant: str, c: dict) -> EffectFamily:
    return EffectFamily("actuator_lag", variant, "s", 1e-4, 5e-3, lambda m: Effects(actuator_lag_s=m), {})


def _ripple(variant: str, c: dict) -> EffectFamily:
    rng = c["rng"]
    periods, phase = int(rng.choice((1, 2, 4))), rng.uniform(0, 2 * math.pi)
    return EffectFamily("friction_ripple", variant, "1", 0.05, 0.5,
                        lambda m: Effects(friction_ripple=FrictionRipple(m, periods, phase)),
                        {"periods_per_rev": periods, "phase": phase})


def merge(*effects: Effects) -> Effects:
    """One Effects with every effect that is on in any of ``effects`` (they must not set the same field)."""
    out: dict = {}
    for eff in effects:
        for f in fields(Effects):
            value = getattr(eff, f.name)
            if value in (None, 0.0):
                continue
            if f.name in out:
                raise ValueError(f"two effects set {f.name}")
            out[f.name] = value
    return replace(Effects(), **out)


def weak_magnitude(family: EffectFamily, signal: Callable[[Effects], float], target: float) -> tuple[float, float,
                                                                                                     int]:
    """The magnitude whose signal is ``target`` (see the module docstring): (magnitude, its signal, runs)."""
    m, p = min(family.prior, family.cap), 1.0
    history: list[tuple[float, float]] = []
    for _ in range(SEARCH_MAX_RUNS):
        s = signal(family.build(m))
        history.append((m, s))
        if s > 0.0 and abs(s / target - 1.0) <= SEARCH_TOLERANCE:
            break
        if s <= 0.0:
            m_next = m * 10.0
        else:
            if len(history) >= 2 and history[-2][1] > 0.0 and history[-2][0] != m:
                (m0, s0), (m1, s1) = history[-2], history[-1]
                slope = math.log(s1 / s0) / math.log(m1 / m0) if s1 != s0 else 1.0
                p = min(4.0, max(0.25, slope))
            m_next = m * (target / s) ** (1.0 / p)
        if m >= family.cap and m_next >= family.cap:
            break
        m = min(m_next, family.cap)
    best = min(history, key=lambda h: abs(math.log(max(h[1], 1e-300) / target)))
    return best[0], best[1], len(history)
