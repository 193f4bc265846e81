"""The unknowns of library effects in a two-inertia fit, scaled by what the log shows.

Every effect's unknowns are *coordinates* x with ``value = scale * x`` (``scale * exp(x)`` for a log coordinate),
chosen so that x = 0 is the effect switched off wherever that is possible (the screen tests x = 0, and the fit can
reach it smoothly), and x ~ 1 is an effect of the size the log would show plainly. The scales come from the
drive's data sheet (J_m, f_m, r from the sidecar) and from the log through the base fit (``LogScales``), never
from a test log's values:

==================== ====================================== ===============================================
effect               coordinates                            scale
==================== ====================================== ===============================================
viscous_motor        b_m                                    f_m / v_m (viscous torque = f_m at typical speed)
viscous_load         b_l                                    f_l / v_l (base fit's f_l, typical load speed)
stribeck             ratio s; ln v_s                        1; v_l
asymmetric_friction  a                                      1
hardening            hardening                              1 / d95^2 (d95: the deflections the log shows)
hysteresis           H; ln(delta), delta = H / sigma        K_s d95 (the spring torque seen); d95
kinematic_error      c = A cos(phi), s = A sin(phi);        d95
                     c4, s4 the same of A4, phi4
==================== ====================================== ===============================================

The Stribeck velocity is searched down to a tenth of the load's 5 % slip speed (``stribeck_speeds``), no lower: a
decay below every speed the log shows is the same static level for any smaller velocity, and costs the exact
simulation substeps in proportion.

v_m, v_l: median speed of the motor / load while it slips; d95: 95th percentile of |deflection|; both from the
base model's simulation of the training part (the model reproduces the log closely; the raw deflection r q_m - q_l
is quantised by the encoder far above the deflections that matter). The hysteresis is written with its saturation
deflection delta = H / sigma (where the Dahl element stops stiffening), because at small H the element's torque is
H times a function of the motion and delta: linear in H, so the screen can test H = 0 on a grid of delta. The
kinematic error A sin(2 q_m + phi) = c sin(2 q_m) + s cos(2 q_m) is linear in (c, s) at 0, and so is its second
harmonic A4 sin(4 q_m + phi4) in (c4, s4). A harmonic drive's transmission error is periodic in the wave generator's
turn, twice per turn first (the flexspline's two lobes) with its harmonics beside it; the 4/rev is the first of them.
It is fitted where the log's motor angles tell it from the 2/rev (``harmonic_separation``): over an arc much shorter
than a period (a few hundredths of a turn, as in the default design's logs) the two are the same local curve, and a
fit of both only adds variance (measured on an independent simulator's log: with the 4/rev beside it, the 2/rev's
refit predicted the held-back data 1.021x better instead of 1.025x, and its detection limit grew 70x); over turns
of the motor (torque steps) they are apart. The screen tests every coordinate fitted together; the magnitude a report
quotes, and its detection limit, is the 2/rev amplitude A (``SIZE_COORDS``), the 4/rev partialled out.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...model.effects import EFFECTS
from ...model.params import DriveParams

#: the kinematic error's coordinates (2/rev, then 4/rev; the names after ``kinematic_``)
KINEMATIC_COORDS = ("c", "s", "c4", "s4")
#: the linear coordinates whose values make an effect's magnitude, where not all of them do
SIZE_COORDS = {"kinematic_error": ("kinematic_c", "kinematic_s")}
#: effects of the two-inertia model, in the library's order
TWO_INERTIA_EFFECTS = ("viscous_motor", "viscous_load", "stribeck", "asymmetric_friction", "hardening", "hysteresis",
                       "kinematic_error")


@dataclass(frozen=True)
class LogScales:
    """What the log shows, through the base fit: typical slip speeds [rad/s], deflection scale [rad], and the
    percentiles of the load's slip speed (the Stribeck grid)."""

    v_m: float
    v_l: float
    d95: float
    v_l_percentiles: tuple[float, ...]     # 5, 25, 50, 75, 95 % of |v_l| while the load slips
    K_s: float
    f_l: float
    f_m: float
    #: the 2/rev kinematic error's information the 4/rev leaves it over the log's motor angles (1: apart, 0: one)
    harmonic_separation: float = 0.0

    @property
    def kinematic_harmonics(self) -> tuple[int, ...]:
        """The kinematic error's harmonics a fit can tell apart on this log: the 4/rev beside the 2/rev where
        fitting it leaves the 2/rev at least half its information (its limit and interval grow by at most sqrt 2),
        the 2/rev alone where the motor turned too little to tell the two apart."""
        return (2, 4) if self.harmonic_separation >= 0.5 else (2,)

    @classmethod
    def from_simulation(cls, sim: dict[str, np.ndarray], stop: int, base: DriveParams) -> "LogScales":
        v_m, v_l = np.abs(sim["v_m"][:stop]), np.abs(sim["v_l"][:stop])
        slip_m, slip_l = v_m[v_m > 0], v_l[v_l > 0]
        # a log where a body never slips gives the data sheet's own speed scale sqrt(f_m / J_m) (rad/s)
        v0 = math.sqrt(base.f_m / base.J_m)
        vm = float(np.median(slip_m)) if slip_m.size else v0
        vl = float(np.median(slip_l)) if slip_l.size else base.r * v0
        pct = tuple(float(x) for x in np.percentile(slip_l, [5, 25, 50, 75, 95])) if slip_l.size else (vl,) * 5
        d = sim["spring_torque"][:stop] / base.K_s
        d95 = float(np.percentile(np.abs(d), 95)) or base.f_m / (base.r * base.K_s)
        return cls(vm, vl, d95, pct, base.K_s, base.f_l, base.f_m, harmonic_separation(sim["q_m"][:stop]))

    def describe(self) -> list[str]:
        pct = ", ".join(f"{v:.3g}" for v in self.v_l_percentiles)
        return [f"typical slip speeds (medians while slipping, base model on the training part): motor {self.v_m:.4g} "
                f"rad/s, load {self.v_l:.4g} rad/s; load slip speed percentiles 5/25/50/75/95 %: {pct} rad/s",
                f"deflection scale d95 (95th percentile of |deflection| of the base model): {self.d95:.4g} rad; "
                f"spring torque scale K_s d95 = {self.K_s * self.d95:.4g} N.m",
                "kinematic error: " + (f"its 2/rev alone fitted; {self.kinematic_doubt}" if self.kinematic_doubt else
                                       "its 2/rev and 4/rev harmonics fitted (the 2/rev keeps "
                                       f"{self.harmonic_separation:.3g} of its information beside the 4/rev, which "
                                       "is fitted from 0.5)")]

    @property
    def kinematic_doubt(self) -> str:
        """Why a kinematic error's quoted size may not be the drive's 2/rev ('' where the 4/rev is fitted beside
        it): the derivations and a named error's doubts say it in these words."""
        if 4 in self.kinematic_harmonics:
            return ""
        return (f"its size is the 2/rev alone: over this log's motor angles the 4/rev cannot be told from it (the "
                f"2/rev keeps {self.harmonic_separation:.2g} of its information beside it; the 4/rev is fitted from "
                "0.5), so the amplitude is the 2/rev that reproduces the local shape, not necessarily the drive's; "
                "record a motor move over a few turns")


def harmonic_separation(q_m: np.ndarray) -> float:
    """How well the motor angles ``q_m`` [rad] tell the kinematic error's 2/rev from its 4/rev: the share of the
    2/rev's information (the smallest eigenvalue of its sine and cosine columns' Gram matrix, the encoder offset and
    the gear ratio partialled out, which any model fits) that is left once the 4/rev's columns are partialled out
    too. Over a motor arc much shorter than a period both are the same local curve (measured on 10 s logs of an
    independent simulator: 1e-7 over the default design's 0.06-0.1 rad of motor travel, 0.98-0.997 over torque steps'
    21 rad)."""
    q = np.asarray(q_m, dtype=float)
    if q.size < 8:
        return 0.0
    G, _ = np.linalg.qr(np.column_stack([np.ones_like(q), q - q.mean()]))
    F = np.column_stack([np.sin(2 * q), np.cos(2 * q), np.sin(4 * q), np.cos(4 * q)])
    Z = F - G @ (G.T @ F)
    two = np.linalg.eigvalsh(Z[:, :2].T @ Z[:, :2])[0]
    Q4, _ = np.linalg.qr(Z[:, 2:])
    rest = Z[:, :2] - Q4 @ (Q4.T @ Z[:, :2])
    return float(np.linalg.eigvalsh(rest.T @ rest)[0] / two) if two > 0 else 0.0


@dataclass(frozen=True)
class Coord:
    """One unknown of an effect: ``value = scale * x`` (``log``: ``scale * exp(x)``), x in [lo, hi];
    ``from_zero``: x = 0 is the effect off and x may only grow from there (a one-sided score test)."""

    effect: str
    name: str
    lo: float
    hi: float
    scale: float
    log: bool = False
    from_zero: bool = False

    def value(self, x: float) -> float:
        return self.scale * math.exp(x) if self.log else self.scale * x

    def x_of(self, value: float) -> float:
        return math.log(max(value, 1e-300) / self.scale) if self.log else value / self.scale

    def rescaled(self, scale: float) -> "Coord":
        """The same unknown with ``value = scale * x`` (a linear coordinate; its bounds keep their values)."""
        if self.log or scale <= 0:
            return self
        f = self.scale / scale
        return Coord(self.effect, self.name, self.lo * f, self.hi * f, scale, self.log, self.from_zero)


def coordinates(name: str, s: LogScales, sensitivity: dict[str, float] | None = None) -> tuple[Coord, ...]:
    """The unknowns of effect ``name`` (see the module docstring for the scales). ``sensitivity``: for a linear
    coordinate, the value that moves the load by one noise sigma (RMS) at the model where the effect was screened;
    it then becomes the coordinate's scale, so that the fit sees x ~ 1 as a just-visible effect (IPOPT pushes a
    start off its bounds by 0.01 in x and scales its problem by the gradients: both need x of order 1)."""
    coords = _coordinates(name, s)
    if not sensitivity:
        return coords
    return tuple(c.rescaled(sensitivity[c.name]) if c.name in sensitivity else c for c in coords)


def _coordinates(name: str, s: LogScales) -> tuple[Coord, ...]:
    d_cap = 1.0 / s.d95  # the FMU takes a kinematic error up to 1 rad
    table = {
        "viscous_motor": (Coord(name, "b_m", 0.0, 1e4, s.f_m / s.v_m, from_zero=True),),
        "viscous_load": (Coord(name, "b_l", 0.0, 1e4, max(s.f_l, 1e-3 * s.f_m) / s.v_l, from_zero=True),),
        "stribeck": (Coord(name, "stribeck_ratio", 0.0, 10.0, 1.0, from_zero=True),
                     Coord(name, "ln_stribeck_velocity", math.log(stribeck_speeds(s)[0] / s.v_l), math.log(1e3),
                           s.v_l, log=True)),
        "asymmetric_friction": (Coord(name, "friction_asymmetry", -0.99, 0.99, 1.0),),
        "hardening": (Coord(name, "hardening", 0.0, 1e4, 1.0 / s.d95**2, from_zero=True),),
        "hysteresis": (Coord(name, "hysteresis_torque", 0.0, 1e3, s.K_s * s.d95, from_zero=True),
                       Coord(name, "ln_saturation_deflection", math.log(1e-3), math.log(1e2), s.d95, log=True)),
        "kinematic_error": tuple(Coord(name, f"kinematic_{k}", -min(1e3, d_cap), min(1e3, d_cap), s.d95)
                                 for k in KINEMATIC_COORDS[:2 * len(s.kinematic_harmonics)]),
    }
    return table[name]


_STIFFNESS_RANGE = next((f.lo, f.hi) for f in EFFECTS["hysteresis"].fit_vars if f.param == "hysteresis_stiffness")


def fmu_values(name: str, coords: tuple[Coord, ...], x: np.ndarray) -> dict[str, float]:
    """The FMU parameters of effect ``name`` at coordinates ``x``."""
    v = {c.name: c.value(float(xi)) for c, xi in zip(coords, x)}
    if name == "stribeck":
        return {"stribeck_ratio": v["stribeck_ratio"], "stribeck_velocity": v["ln_stribeck_velocity"]}
    if name == "hysteresis":
        H = v["hysteresis_torque"]
        # H = 0 is the element off; its stiffness is then irrelevant (any value in the FMU's range). A tiny H over a
        # wide saturation deflection asks for a stiffness below the FMU's range (log 5216 of the diagnosis matrix):
        # the range's end then stands for it (the element is negligible there either way).
        lo, hi = _STIFFNESS_RANGE
        return {"hysteresis_torque": H,
                "hysteresis_stiffness": min(max(H / v["ln_saturation_deflection"], lo), hi) if H > 0 else 1.0}
    if name == "kinematic_error":
        c, s, c4, s4 = (v.get(f"kinematic_{k}", 0.0) for k in KINEMATIC_COORDS)
        return {"kinematic_error": math.hypot(c, s), "kinematic_error_phase": math.atan2(s, c),
                "kinematic_error_4": math.hypot(c4, s4), "kinematic_error_4_phase": math.atan2(s4, c4)}
    return v


def grid(name: str, s: LogScales) -> list[dict[str, float]]:
    """The screen's grid of effect ``name``'s nonlinear coordinates (empty dict: the effect has none).

    Stribeck velocity: 8 geometric steps from a tenth of the load's 5 % slip speed (the decay finished below every
    speed seen: a static level above the sliding one) to its 95 % slip speed. Hysteresis saturation deflection:
    0.03, 0.1, 0.3 and 1 x d95, from an element that saturates at once to one that never does."""
    if name == "stribeck":
        return [{"ln_stribeck_velocity": math.log(v / s.v_l)} for v in np.geomspace(*stribeck_speeds(s), 8)]
    if name == "hysteresis":
        return [{"ln_saturation_deflection": math.log(f)} for f in (0.03, 0.1, 0.3, 1.0)]
    return [{}]


#: the screen's gridded coordinates in words: (what it is, its value's unit)
GRID_WORDS = {"ln_stribeck_velocity": ("Stribeck velocity", "rad/s"),
              "ln_saturation_deflection": ("saturation deflection", "rad")}


def grid_words(c: Coord, x: float) -> str:
    """A gridded coordinate at ``x`` in words, e.g. 'Stribeck velocity 0.0012 rad/s'."""
    what, unit = GRID_WORDS.get(c.name, (c.name, ""))
    return f"{what} {c.value(x):.3g} {unit}".rstrip()


def record_advice(name: str, s: LogScales, motor_span: float) -> str:
    """What a log would have to show for a smaller effect ``name`` to be seen, with what this one shows
    (``motor_span``: how far the motor turned over the training part [rad])."""
    p5, p95 = s.v_l_percentiles[0], s.v_l_percentiles[-1]
    return {
        "viscous_motor": f"faster motor slides (its median slip speed here: {s.v_m:.3g} rad/s): the viscous torque "
                         "grows with speed",
        "viscous_load": f"faster load slides (its median slip speed here: {s.v_l:.3g} rad/s)",
        "stribeck": f"slides that pass slowly through the speeds where static friction gives way (the load's slip "
                    f"speeds here: {p5:.3g} to {p95:.3g} rad/s, 5 to 95 %)",
        "asymmetric_friction": "moves in both directions at the same speeds",
        "hardening": f"larger deflections (95 % of them stay below {s.d95:.3g} rad here): the stiffening grows with "
                     "the deflection squared",
        "hysteresis": f"reversals of the spring's twist well beyond its deflection scale here ({s.d95:.3g} rad)",
        "kinematic_error": f"a motor move over at least one period of the error (pi rad of motor angle; the motor "
                           f"turned through {motor_span:.3g} rad here): over a shorter arc it looks like an encoder "
                           "offset and a gear-ratio error",
    }.get(name, "")


def stribeck_speeds(s: LogScales) -> tuple[float, float]:
    """The Stribeck velocities the screen's grid spans [rad/s]: from a tenth of the load's 5 % slip speed to its 95 %
    slip speed. The lower end is also the fits' lower bound: a decay that ends below every speed the log shows is
    seen only as a static level above the sliding one, the same for any smaller velocity (the time a body spends
    below v_s shrinks with it), while the exact simulation's substeps through it shrink as v_s (measured on a
    two-effect log: a Stribeck refit that drifted to 1e-4 of the median slip speed took 0.9 s per simulation of the
    training part instead of 0.06 s, 230 s in all)."""
    lo = 0.1 * s.v_l_percentiles[0]
    return lo, max(s.v_l_percentiles[-1], lo * 1.01)


def magnitude_of(name: str, values: dict[str, float]) -> float:
    """The number a report quotes for effect ``name`` (the library's magnitude) from its FMU parameters."""
    key = {"viscous_motor": "b_m", "viscous_load": "b_l", "stribeck": "stribeck_ratio",
           "asymmetric_friction": "friction_asymmetry", "hardening": "hardening", "hysteresis": "hysteresis_torque",
           "kinematic_error": "kinematic_error"}[name]
    return abs(values[key]) if name == "asymmetric_friction" else values[key]
