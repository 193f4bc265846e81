"""The effect library of the discrepancy workflow: one entry per physical effect, written once in CasADi.

Every effect of ``physics.md`` section 5 is an optional, default-off term. Its parameters are FMU parameters of the
variable table (``fmu_build/variables.py``, value references 100+), and the C model (``fmu_build/c/model.c``)
implements exactly the formulas below; ``tests/test_effects.py`` holds the two equal on trajectories of the FMU.

Equations (SI, load-side angles; ``dir`` is a slipping body's direction, +1 / -1)::

    d     = r q_m + e(q_m) - q_l                              deflection incl. kinematic error
    e     = A sin(2 q_m + phi) + A4 sin(4 q_m + phi4)         twice and four times per wave-generator turn
    g     = r + e'(q_m)                                       d(d)/d(q_m): the transmission seen by the motor
    tau_s = K_s (d + hardening d^3) + z                       spring torque (hardening = K3/K_s; at an exponent
                                                              p != 2, d |d|^p d_h^(2 - p) for d^3)
    z'    = sigma dd |1 - sgn(dd) z/H|^n sgn(1 - sgn(dd) z/H),  dd = g v_m - v_l   Dahl hysteresis (H = 0: off)
    J_m v_m' = T - g tau_s - F_m          J_l v_l' = tau_s - F_l
    F     = dir f (1 + a dir)(1 + s exp(-|v/v_s|^delta)) + b (1 + a_v dir) v   a slipping body's friction
    static band of a stuck body: -f (1 - a)(1 + s) <= N <= f (1 + a)(1 + s)

``a`` = ``friction_asymmetry``, ``a_v`` = ``viscous_asymmetry`` (the viscous coefficient is b (1 + a_v) moving
forwards, b (1 - a_v) backwards; both bodies), ``s`` = ``stribeck_ratio``, ``v_s`` = ``stribeck_velocity`` on the
load side and ``stribeck_velocity / r`` on the motor side, ``delta`` = ``stribeck_shape`` (2, the default: a Gaussian
decay; 1: an exponential one; the diagnosis fits the Gaussian and checks a named size against the exponential),
``b`` = ``b_m`` / ``b_l``, ``n`` = ``hysteresis_exponent`` (1, the default: the classic Dahl element, an exponential
approach to H along a branch; larger: an algebraic one).

The rigid model (one body seen through the motor encoder, e.g. a linear axis in N and m) uses the same friction
law: ``T = M q'' + F(q') + offset``; with both asymmetries it is the EMPS paper's ``Fc+, Fc-, Fv+, Fv-`` model
(``Fc+- = Fc (1 +- a)``, ``Fv+- = Fv (1 +- a_v)``).

The effect ``asymmetric_friction`` has two unknowns: the Coulomb asymmetry ``friction_asymmetry`` and the viscous
asymmetry ``viscous_asymmetry`` (which only acts where there is viscous friction).

Each :class:`Effect` knows its FMU parameters (with their physical bounds), its *magnitude* (the number a report
quotes, with its unit) and the residual signature it leaves (used to explain the choice). How a fit scales and
starts them is the diagnosis's business (``ident.diagnosis.models.coordinates``): it derives both from the drive's
data sheet and the log, never from fixed values.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

import casadi as ca

# ------------------------------------------------------------------------------------------ CasADi terms --------


def kinematic_error(q_m: Any, kin: tuple[Any, Any, Any, Any] = (0.0, 0.0, 0.0, 0.0)) -> Any:
    """e = A sin(2 q_m + phi) + A4 sin(4 q_m + phi4) [rad, load side]; ``kin`` = (A, phi, A4, phi4)."""
    return kin[0] * ca.sin(2 * q_m + kin[1]) + kin[2] * ca.sin(4 * q_m + kin[3])


def deflection(q_m: Any, q_l: Any, r: Any, kin: tuple[Any, Any, Any, Any] = (0.0, 0.0, 0.0, 0.0)) -> Any:
    """d = r q_m + e(q_m) - q_l [rad, load side]."""
    return r * q_m + kinematic_error(q_m, kin) - q_l


def transmission(q_m: Any, r: Any, kin: tuple[Any, Any, Any, Any] = (0.0, 0.0, 0.0, 0.0)) -> Any:
    """g = d(d)/d(q_m) = r + 2 A cos(2 q_m + phi) + 4 A4 cos(4 q_m + phi4): the factor by which the spring torque
    acts on the motor."""
    return r + 2 * kin[0] * ca.cos(2 * q_m + kin[1]) + 4 * kin[2] * ca.cos(4 * q_m + kin[3])


def spring_torque(d: Any, K_s: Any, hardening: Any = 0.0, z: Any = 0.0, exponent: Any = 2.0,
                  deflection: Any = 1.0) -> Any:
    """tau_s = K_s (d + hardening d^3) + z [N m]; at a hardening ``exponent`` p other than 2, d^3 becomes
    d |d|^p d_h^(2 - p) (d_h = ``deflection``: where it stiffens as the cubic does)."""
    if isinstance(exponent, (int, float)) and exponent == 2.0:
        return K_s * (d + hardening * d**3) + z
    return K_s * (d + hardening * d * ca.fabs(d) ** exponent * deflection ** (2 - exponent)) + z


def hysteresis_rate(z: Any, dd: Any, sigma: Any, H: Any, exponent: Any = 1.0) -> Any:
    """Dahl element: z' = sigma dd |1 - sgn(dd) z/H|^n sgn(1 - sgn(dd) z/H) [N m/s]; dd is the deflection rate; the
    default n = 1 as sigma (dd - |dd| z/H)."""
    if isinstance(exponent, (int, float)) and exponent == 1.0:
        return sigma * (dd - ca.fabs(dd) * z / H)
    u = 1 - ca.sign(dd) * z / H
    return sigma * dd * ca.fabs(u) ** exponent * ca.sign(u)


def friction_level(direction: Any, f: Any, asymmetry: Any = 0.0) -> Any:
    """Coulomb level for motion in ``direction`` (+1/-1): f (1 + a dir) [N m]."""
    return f * (1 + asymmetry * direction)


def sliding_friction(v: Any, f: Any, *, b: Any = 0.0, asymmetry: Any = 0.0, stribeck_ratio: Any = 0.0,
                     stribeck_velocity: Any = 1.0, viscous_asymmetry: Any = 0.0, direction: Any | None = None,
                     stribeck_shape: Any = 2.0) -> Any:
    """Friction torque on a slipping body (the term subtracted in J v' = ... - F):
    dir f (1 + a dir)(1 + s exp(-|v/v_s|^delta)) + b (1 + a_v dir) v; ``direction`` defaults to sgn(v)."""
    dirn = ca.sign(v) if direction is None else direction
    return dirn * friction_level(dirn, f, asymmetry) * (1 + stribeck_ratio * stribeck_decay(v / stribeck_velocity,
                                                                                          stribeck_shape)) \
        + b * (1 + viscous_asymmetry * dirn) * v


def stribeck_decay(x: Any, shape: Any = 2.0) -> Any:
    """exp(-|x|^delta), x = v / v_s; the default delta = 2 as exp(-x^2) (the FMU computes it so too)."""
    if isinstance(shape, (int, float)) and shape == 2.0:
        return ca.exp(-x ** 2)
    return ca.exp(-ca.fabs(x) ** shape)


def static_band(f: Any, asymmetry: Any = 0.0, stribeck_ratio: Any = 0.0) -> tuple[Any, Any]:
    """(lower, upper) net torque a stuck body withstands: -f(1-a)(1+s), f(1+a)(1+s)."""
    return -f * (1 - asymmetry) * (1 + stribeck_ratio), f * (1 + asymmetry) * (1 + stribeck_ratio)


def slip_dynamics(params: dict[str, Any]) -> ca.Function:
    """CasADi function of the two-inertia model with both bodies slipping:
    x = [q_m, q_l, v_m, v_l, z], u = T  ->  x' and the outputs [d, tau_s, F_m, F_l]. ``params`` maps FMU parameter
    names to numbers or CasADi symbols (missing effect parameters are off)."""
    p = {**EFFECT_DEFAULTS, **params}
    x, u = ca.SX.sym("x", 5), ca.SX.sym("T")
    q_m, q_l, v_m, v_l, z = (x[i] for i in range(5))
    kin = tuple(p[k] for k in KINEMATIC_ERROR_PARAMS)
    d = deflection(q_m, q_l, p["r"], kin)
    g = transmission(q_m, p["r"], kin)
    tau = spring_torque(d, p["K_s"], p["hardening"], z, p["hardening_exponent"], p["hardening_deflection"])
    common = dict(asymmetry=p["friction_asymmetry"], stribeck_ratio=p["stribeck_ratio"],
                  viscous_asymmetry=p["viscous_asymmetry"], stribeck_shape=p["stribeck_shape"])
    F_m = sliding_friction(v_m, p["f_m"], b=p["b_m"], stribeck_velocity=p["stribeck_velocity"] / p["r"], **common)
    F_l = sliding_friction(v_l, p["f_l"], b=p["b_l"], stribeck_velocity=p["stribeck_velocity"], **common)
    H = p["hysteresis_torque"]
    dz = hysteresis_rate(z, g * v_m - v_l, p["hysteresis_stiffness"], H, p["hysteresis_exponent"]) \
        if _nonzero(H) else 0 * z
    xdot = ca.vertcat(v_m, v_l, (u - g * tau - F_m) / p["J_m"], (tau - F_l) / p["J_l"], dz)
    return ca.Function("slip_dynamics", [x, u], [xdot, ca.vertcat(d, tau, F_m, F_l)], ["x", "T"], ["xdot", "y"])


def rigid_force(a: Any, v: Any, theta: dict[str, Any]) -> Any:
    """The rigid model's force/torque: M a + F(v) + offset, F with viscous ``Fv``, Coulomb ``Fc``, (Coulomb)
    ``asymmetry``, ``viscous_asymmetry``, Stribeck (ratio, velocity) from ``theta`` (missing terms are off)."""
    return theta["M"] * a + sliding_friction(v, theta["Fc"], b=theta.get("Fv", 0.0),
                                             asymmetry=theta.get("asymmetry", 0.0),
                                             stribeck_ratio=theta.get("stribeck_ratio", 0.0),
                                             stribeck_velocity=theta.get("stribeck_velocity", 1.0),
                                             viscous_asymmetry=theta.get("viscous_asymmetry", 0.0)) \
        + theta.get("offset", 0.0)


def _nonzero(x: Any) -> bool:
    return not (isinstance(x, (int, float)) and x == 0)


# ------------------------------------------------------------------------------------------ the registry -------

EFFECT_DEFAULTS: dict[str, float] = {
    "b_m": 0.0, "b_l": 0.0, "stribeck_ratio": 0.0, "stribeck_velocity": 1e-3, "friction_asymmetry": 0.0,
    "hardening": 0.0, "hysteresis_torque": 0.0, "hysteresis_stiffness": 1.0e4, "kinematic_error": 0.0,
    "kinematic_error_phase": 0.0, "viscous_asymmetry": 0.0, "kinematic_error_4": 0.0, "kinematic_error_4_phase": 0.0,
    "stribeck_shape": 2.0, "hysteresis_exponent": 1.0, "hardening_exponent": 2.0, "hardening_deflection": 1.0,
}
#: the kinematic error's FMU parameters, in the order of ``kin`` above: (A, phi, A4, phi4)
KINEMATIC_ERROR_PARAMS = ("kinematic_error", "kinematic_error_phase", "kinematic_error_4", "kinematic_error_4_phase")


@dataclass(frozen=True)
class FitVar:
    """One FMU parameter of an effect and its physical range [lo, hi]."""

    param: str          # FMU parameter it sets
    lo: float
    hi: float


@dataclass(frozen=True)
class Effect:
    """One effect of the library.

    ``magnitude(values)`` turns fitted FMU parameter values into the number the report quotes (``unit``).
    ``signature`` says in words what the effect leaves in the residuals; ``applies_to`` the base models it extends.
    """

    name: str
    fit_vars: tuple[FitVar, ...]
    unit: str
    signature: str
    applies_to: tuple[str, ...]
    magnitude: Callable[[dict[str, float]], float]
    magnitude_param: str | None  # FMU parameter whose interval is the magnitude's (None: derived)


# FitVar ranges: the FMU's (fmu_build/variables.py), except where a physical limit is tighter
EFFECTS: dict[str, Effect] = {e.name: e for e in (
    Effect("viscous_motor", (FitVar("b_m", 0.0, 1e6),), "N.m.s/rad",
           "residual grows with motor speed: long slides end too far (or too short) by an amount that scales "
           "with the slide's speed", ("two-inertia", "rigid"), lambda v: v["b_m"], "b_m"),
    Effect("viscous_load", (FitVar("b_l", 0.0, 1e6),), "N.m.s/rad",
           "load ringing decays exponentially (constant ratio of successive peaks) instead of linearly (Coulomb)",
           ("two-inertia",), lambda v: v["b_l"], "b_l"),
    Effect("stribeck", (FitVar("stribeck_ratio", 0.0, 10.0), FitVar("stribeck_velocity", 1e-12, 1e6)),
           "1", "breakaway needs more torque than sliding: overshoot after breakaway, a dip of friction at low speed",
           ("two-inertia", "rigid"), lambda v: v["stribeck_ratio"], "stribeck_ratio"),
    Effect("asymmetric_friction", (FitVar("friction_asymmetry", -0.99, 0.99), FitVar("viscous_asymmetry", -0.99, 0.99)),
           "1", "the residual's sign follows the direction of motion: positive and negative moves end at different "
           "distances", ("two-inertia", "rigid"), lambda v: abs(v["friction_asymmetry"]), "friction_asymmetry"),
    Effect("hardening", (FitVar("hardening", 0.0, 1e20),), "1/rad2",
           "ringing frequency rises with amplitude: phase error grows in large swings and vanishes in small ones",
           ("two-inertia",), lambda v: v["hardening"], "hardening"),
    Effect("hysteresis", (FitVar("hysteresis_torque", 0.0, 1e6), FitVar("hysteresis_stiffness", 1e-3, 1e15)),
           "N.m", "a loop in spring torque vs twist: direction-dependent offset and amplitude-dependent damping of "
           "the ringing", ("two-inertia",), lambda v: v["hysteresis_torque"], "hysteresis_torque"),
    Effect("kinematic_error", (FitVar("kinematic_error", 0.0, 1.0), FitVar("kinematic_error_phase", -10.0, 10.0),
                               FitVar("kinematic_error_4", 0.0, 1.0), FitVar("kinematic_error_4_phase", -10.0, 10.0)),
           "rad", "load angle error periodic in motor angle, twice (and four times) per wave-generator turn",
           ("two-inertia",), lambda v: v["kinematic_error"], "kinematic_error"),
    Effect("flexibility", (), "N.m/rad", "a resonance the rigid model cannot produce: the load rings on its own "
           "after every move while the motor stands still", ("rigid",), lambda v: v.get("K_s", math.nan), "K_s"),
)}


def active_effects(values: dict[str, float]) -> list[str]:
    """Names of the effects switched on by a set of FMU parameter values."""
    on = []
    for name, e in EFFECTS.items():
        if e.fit_vars and values.get(e.fit_vars[0].param, 0.0) != 0.0:
            on.append(name)
    return on
