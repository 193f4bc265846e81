"""The plant of the reference log generator: a two-inertia harmonic drive with exact stick-slip, and the effects
real drives show, written as a hybrid system (continuous state + discrete mode) in this module's own words.

Independent of the product: nothing here comes from ``fmu_build/c/model.c`` or ``ident/``; it implements
``physics.md`` sections 1 and 5, plus effect *shapes* the product's library does not have (see ``Effects``).

Continuous state ``x`` (SI, load-side deflection ``d``): ``[q_m, q_l, v_m, v_l]``, then, when present, the torque
that reaches the motor ``T_a`` (actuator lag), the Dahl state ``z``, the forces ``w_i`` of the Maxwell-slip
elements, and (``track_energy``) the works ``W_in, W_fric, W_hyst`` [J]::

    d      = r q_m + e(q_m) - q_l           e: kinematic error, e(q) = A2 sin(2q + p2) + A4 sin(4q + p4)
    g      = r + e'(q_m)                    the transmission the motor sees (virtual work: energy-consistent)
    tau_s  = S(d) + z + sum w_i             S: linear, cubic K(d + h d^3) or the catalog's three slopes
    dd     = g v_m - v_l                    deflection rate
    J_m v_m' = T_a - g tau_s - F_m          J_l v_l' = tau_s - F_l        (a stuck body: v = 0, v' = 0)
    T_a'   = (T_cmd - T_a) / tau_a          first-order current loop (off: T_a = T_cmd)
    z'     = sigma dd |1 - s z/H|^n sgn(1 - s z/H),  s = sgn(dd)      Dahl
    w_i'   = k_i dd while |w_i| < F_i (stuck element), 0 while it slides

Friction of a slipping body moving in direction ``s`` (+1/-1)::

    F = s f (1 + a s) R(q_m) (1 + rho phi(|v| / v_s)) + b v,   phi = exp(-x) or exp(-x^2)

and a stuck body holds while its net non-friction torque N (motor ``T_a - g tau_s``, load ``tau_s``) lies in
``[-f (1 - a)(1 + rho0) R, f (1 + a)(1 + rho0) R]``; ``rho0 >= rho`` is the static (breakaway) level, ``R`` the
friction ripple ``1 + eps sin(n q_m + phase)`` (motor only). Karnopp: a body at v = 0 stays stuck while N is in its
band, else breaks away along N; a slipping body whose velocity reaches 0 is decided again.

The mode is ``(motor, load, region, dahl, maxwell...)``: each body 0 (stuck) or its slip direction; the stiffness
region of the three-slope spring (-2..2); the sign of dd the Dahl element assumes; each Maxwell element 0 (stuck)
or its slide direction. Within a mode the right-hand side is smooth; every mode change is the zero of a *guard*
(a function that is >= 0 while the mode holds), located by the engines (``engines.py``).
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Literal

MOTOR, LOAD = 0, 1
STUCK = 0
Mode = tuple[int, ...]
Vector = list[float]


# --------------------------------------------------------------------------------------------- the drive ------

@dataclass(frozen=True)
class Drive:
    """The base drive (SI): the quantities of physics.md section 2 plus the encoder."""

    J_m: float = 2e-5                    # motor + wave generator inertia [kg m^2]
    f_m: float = 0.01                    # motor Coulomb friction [N m]
    K_s: float = 1e4                     # torsional stiffness (small-deflection slope) [N m/rad]
    J_l: float = 0.05                    # flexspline + arm inertia [kg m^2]
    f_l: float = 1e-3                    # load Coulomb friction [N m]
    r: float = 0.01                      # gear ratio q_l / q_m
    arm_length: float = 0.3              # [m]
    encoder_counts_per_rev: int = 12566

    @classmethod
    def from_nondim(cls, K_star: float, J_l_star: float, f_l_star: float, **si: float) -> Drive:
        """A drive from K* = K_s/f_m [1/rad], J_l* = J_l/J_m, f_l* = f_l/f_m (J_m, f_m, ... from ``si``)."""
        base = cls(**si)
        return cls(**{**asdict(base), "K_s": K_star * base.f_m, "J_l": J_l_star * base.J_m,
                      "f_l": f_l_star * base.f_m})

    @property
    def K_star(self) -> float:
        return self.K_s / self.f_m

    @property
    def J_l_star(self) -> float:
        return self.J_l / self.J_m

    @property
    def f_l_star(self) -> float:
        return self.f_l / self.f_m

    @property
    def T_c(self) -> float:
        """sqrt(J_m/f_m) [s], the time unit of the non-dimensional form."""
        return math.sqrt(self.J_m / self.f_m)

    @property
    def count_rad(self) -> float:
        """One encoder count [rad of the motor]."""
        return 2.0 * math.pi / self.encoder_counts_per_rev

    @property
    def omega_max(self) -> float:
        """An upper bound [rad/s] of the ringing frequencies of the linear plant (both bodies slipping, or one)."""
        return math.sqrt(self.K_s * (self.r**2 / self.J_m + 1.0 / self.J_l))


# --------------------------------------------------------------------------------------------- the effects ----

@dataclass(frozen=True)
class Stribeck:
    """Static level above Coulomb, decaying with speed: sliding level f (1 + ratio phi(|v|/v_s)); the breakaway
    (static) level f (1 + static_ratio) may lie above the sliding curve's value at 0+ (a separate static level)."""

    ratio: float
    velocity: float                      # v_s on the load side [rad/s]; the motor's is velocity / r
    shape: Literal["exponential", "gaussian"] = "exponential"
    static_ratio: float | None = None    # None: the static level is the sliding curve's value at 0+
    bodies: tuple[str, ...] = ("motor", "load")

    def __post_init__(self) -> None:
        if self.shape not in ("exponential", "gaussian"):
            raise ValueError(f"Stribeck shape {self.shape!r}: use 'exponential' or 'gaussian'")
        if self.static_ratio is not None and self.static_ratio < self.ratio:
            raise ValueError(f"Stribeck static_ratio {self.static_ratio} < ratio {self.ratio}: the breakaway level "
                             "must not lie below the sliding level at 0+ (a body would stop at once)")


@dataclass(frozen=True)
class CubicStiffness:
    """Spring torque K (d + hardening d^3); hardening [1/rad^2]."""

    hardening: float


@dataclass(frozen=True)
class ThreeSlopeStiffness:
    """The catalog's piecewise-linear spring: slope K below theta1, k2_ratio K up to theta2, k3_ratio K above
    (odd in d, continuous)."""

    theta1: float
    theta2: float
    k2_ratio: float
    k3_ratio: float

    def __post_init__(self) -> None:
        if not 0.0 < self.theta1 < self.theta2:
            raise ValueError(f"three-slope stiffness: need 0 < theta1 < theta2, got {self.theta1}, {self.theta2}")


@dataclass(frozen=True)
class Dahl:
    """Dahl hysteresis in parallel with the spring: z' = sigma dd |1 - s z/H|^n sgn(1 - s z/H)."""

    torque: float                        # H [N m]: the saturation torque
    stiffness: float                     # sigma [N m/rad]: the initial slope
    exponent: float = 1.0                # n


@dataclass(frozen=True)
class MaxwellSlip:
    """Elasto-slide elements in parallel with the spring: element i is a spring k_i in series with a slider that
    holds up to F_i."""

    stiffnesses: tuple[float, ...]       # k_i [N m/rad]
    break_torques: tuple[float, ...]     # F_i [N m]

    def __post_init__(self) -> None:
        if len(self.stiffnesses) != len(self.break_torques) or not self.stiffnesses:
            raise ValueError("Maxwell-slip: give one break torque per stiffness (at least one element)")


@dataclass(frozen=True)
class KinematicError:
    """Transmission error e(q_m) = amp2 sin(2 q_m + phase2) + amp4 sin(4 q_m + phase4) [rad at the load]."""

    amp2: float
    phase2: float = 0.0
    amp4: float = 0.0
    phase4: float = 0.0


@dataclass(frozen=True)
class FrictionRipple:
    """Motor friction (static and sliding) times 1 + amplitude sin(periods_per_rev q_m + phase)."""

    amplitude: float
    periods_per_rev: int = 2
    phase: float = 0.0


@dataclass(frozen=True)
class Effects:
    """Every effect beyond the base model; all off by default."""

    b_m: float = 0.0                     # motor viscous friction [N m s/rad]
    b_l: float = 0.0                     # load viscous friction [N m s/rad]
    asymmetry_m: float = 0.0             # motor Coulomb levels f_m (1 +- a) for +- motion
    asymmetry_l: float = 0.0             # load Coulomb levels
    stribeck: Stribeck | None = None
    stiffness: CubicStiffness | ThreeSlopeStiffness | None = None
    hysteresis: Dahl | MaxwellSlip | None = None
    kinematic_error: KinematicError | None = None
    actuator_lag_s: float = 0.0          # first-order current-loop time constant [s] (outside the library)
    friction_ripple: FrictionRipple | None = None   # (outside the library)

    def piecewise_linear(self) -> bool:
        """True when every mode's equations are linear with constant forcing (the closed-form engine applies)."""
        return (self.stribeck is None and not isinstance(self.stiffness, CubicStiffness)
                and not isinstance(self.hysteresis, Dahl) and self.kinematic_error is None
                and self.friction_ripple is None)

    def to_dict(self) -> dict:
        """The effects that are on, with their parameters and shape (plain JSON types)."""
        out: dict = {}
        for key, value in asdict(self).items():
            if value in (None, 0.0):
                continue
            obj = getattr(self, key)
            out[key] = {"shape": type(obj).__name__, **value} if isinstance(value, dict) else value
        return out


# --------------------------------------------------------------------------------------------- friction -------

@dataclass(frozen=True)
class _Friction:
    """One body's friction law (see the module docstring)."""

    level: float
    viscous: float = 0.0
    asymmetry: float = 0.0
    ratio: float = 0.0                   # Stribeck sliding excess at 0+
    static_ratio: float = 0.0
    v_s: float = 1.0
    gaussian: bool = False
    ripple: FrictionRipple | None = None

    def ripple_factor(self, q_m: float) -> float:
        rp = self.ripple
        return 1.0 if rp is None else 1.0 + rp.amplitude * math.sin(rp.periods_per_rev * q_m + rp.phase)

    def band(self, q_m: float) -> tuple[float, float]:
        """(lower, upper) net torque a stuck body withstands."""
        scale = self.level * (1.0 + self.static_ratio) * self.ripple_factor(q_m)
        return -scale * (1.0 - self.asymmetry), scale * (1.0 + self.asymmetry)

    def sliding_fn(self, direction: int) -> Callable[[float, float], float]:
        """(v, q_m) -> friction torque of a body slipping in ``direction`` (the term subtracted in J v' = ...)."""
        base = direction * self.level * (1.0 + self.asymmetry * direction)
        b, ratio, v_s, ripple = self.viscous, self.ratio, self.v_s, self.ripple
        if ratio == 0.0 and ripple is None:
            return lambda v, q: base + b * v
        gaussian = self.gaussian
        ripple_factor = self.ripple_factor

        def friction(v: float, q: float) -> float:
            x = abs(v) / v_s
            decay = math.exp(-x * x) if gaussian else math.exp(-x)
            return base * ripple_factor(q) * (1.0 + ratio * decay) + b * v
        return friction


# --------------------------------------------------------------------------------------------- the plant ------

@dataclass(frozen=True)
class Guard:
    """One guard of a mode: ``kind`` (what reaching zero means) and the element it belongs to."""

    kind: str          # "stop", "up", "down" (bodies); "region_lo", "region_hi"; "dahl"; "w_up", "w_down", "w_stop"
    index: int = 0     # body (MOTOR/LOAD) or Maxwell element
    scale: float = 1.0  # typical size, for the round-off tolerance of decisions


class HybridPlant:
    """The drive with its effects as a hybrid system: per-mode right-hand sides and guards, and the Karnopp
    decisions at mode changes. Engines (``engines.py``) integrate it."""

    def __init__(self, drive: Drive, effects: Effects | None = None, track_energy: bool = False) -> None:
        self.drive, self.effects = drive, effects or Effects()
        self.track_energy = track_energy
        self.frictions = self._frictions()
        self._layout()
        self._rhs_cache: dict[Mode, Callable[[Vector, float], Vector]] = {}
        self._guard_cache: dict[Mode, tuple[list[Guard], Callable[[Vector, float], Vector]]] = {}
        self.v_scale = drive.f_m * drive.T_c / drive.J_m          # motor speed a friction-level torque gives
        self.d_scale = max(drive.f_m / drive.r, drive.f_l) / drive.K_s

    # ---- layout and parts ----
    def _frictions(self) -> tuple[_Friction, _Friction]:
        e, d = self.effects, self.drive
        st = e.stribeck

        def law(body: int, level: float, b: float, a: float, v_s_scale: float) -> _Friction:
            on = st is not None and ("motor", "load")[body] in st.bodies
            ratio = st.ratio if on else 0.0
            static = (st.static_ratio if st.static_ratio is not None else st.ratio) if on else 0.0
            return _Friction(level, b, a, ratio, static, st.velocity * v_s_scale if st else 1.0,
                             bool(st and st.shape == "gaussian"), e.friction_ripple if body == MOTOR else None)
        return (law(MOTOR, d.f_m, e.b_m, e.asymmetry_m, 1.0 / d.r), law(LOAD, d.f_l, e.b_l, e.asymmetry_l, 1.0))

    def _layout(self) -> None:
        e = self.effects
        n = 4
        self.i_lag = n if e.actuator_lag_s > 0.0 else -1
        n += self.i_lag >= 0
        self.i_z = n if isinstance(e.hysteresis, Dahl) else -1
        n += self.i_z >= 0
        self.n_elements = len(e.hysteresis.stiffnesses) if isinstance(e.hysteresis, MaxwellSlip) else 0
        self.i_w = n
        n += self.n_elements
        self.i_work = n if self.track_energy else -1
        n += 3 if self.track_energy else 0
        self.n_states = n

    def initial_state(self, q_m: float, d0: float) -> tuple[Vector, Mode]:
        """At rest with deflection ``d0``; hysteresis elements relaxed; the lag settled at zero torque."""
        x = [0.0] * self.n_states
        x[0], x[1] = q_m, self.drive.r * q_m + self.kin_error(q_m) - d0
        mode = (STUCK, STUCK, self.region_of(d0), 1) + (STUCK,) * self.n_elements
        return x, mode

    def kin_error(self, q_m: float) -> float:
        k = self.effects.kinematic_error
        if k is None:
            return 0.0
        return k.amp2 * math.sin(2.0 * q_m + k.phase2) + k.amp4 * math.sin(4.0 * q_m + k.phase4)

    def gear(self, q_m: float) -> float:
        """g = d(d)/d(q_m) = r + e'(q_m)."""
        k = self.effects.kinematic_error
        if k is None:
            return self.drive.r
        return self.drive.r + 2.0 * k.amp2 * math.cos(2.0 * q_m + k.phase2) \
            + 4.0 * k.amp4 * math.cos(4.0 * q_m + k.phase4)

    def deflection(self, x: Vector) -> float:
        return self.drive.r * x[0] + self.kin_error(x[0]) - x[1]

    def load_angle(self, q_m: float, d: float) -> float:
        return self.drive.r * q_m + self.kin_error(q_m) - d

    # ---- the spring ----
    def _breaks(self) -> tuple[float, ...]:
        s = self.effects.stiffness
        return (-s.theta2, -s.theta1, s.theta1, s.theta2) if isinstance(s, ThreeSlopeStiffness) else ()

    def region_of(self, d: float) -> int:
        """Stiffness region of deflection d (-2..2; 0 unless three-slope)."""
        b = self._breaks()
        if not b:
            return 0
        return sum(d > t for t in b) - 2

    def region_bounds(self, region: int) -> tuple[float, float]:
        b = (-math.inf,) + self._breaks() + (math.inf,)
        return (b[region + 2], b[region + 3]) if len(b) > 2 else (-math.inf, math.inf)

    def spring_fn(self, region: int) -> Callable[[float], float]:
        """d -> elastic torque S(d) [N m] (in ``region`` for the three-slope spring)."""
        K, s = self.drive.K_s, self.effects.stiffness
        if isinstance(s, CubicStiffness):
            h = s.hardening
            return lambda d: K * (d + h * d * d * d)
        if isinstance(s, ThreeSlopeStiffness):
            return self._three_slope_fn(region, K, s)
        return lambda d: K * d

    @staticmethod
    def _three_slope_fn(region: int, K: float, s: ThreeSlopeStiffness) -> Callable[[float], float]:
        t1, t2, k2, k3 = s.theta1, s.theta2, s.k2_ratio * K, s.k3_ratio * K
        at1, at2 = K * t1, K * t1 + k2 * (t2 - t1)
        sign = 1.0 if region >= 0 else -1.0
        slope, knee, base = ((K, 0.0, 0.0), (k2, t1, at1), (k3, t2, at2))[abs(region)]
        return lambda d: sign * (base + slope * (sign * d - knee))

    def spring_energy(self, d: float) -> float:
        """Elastic energy of S at deflection d [J] (for energy balances)."""
        K, s = self.drive.K_s, self.effects.stiffness
        if isinstance(s, CubicStiffness):
            return K * (0.5 * d * d + 0.25 * s.hardening * d**4)
        if isinstance(s, ThreeSlopeStiffness):
            a = abs(d)
            e1 = 0.5 * K * min(a, s.theta1) ** 2
            e2 = self._segment_energy(a, s.theta1, s.theta2, s.k2_ratio * K, K * s.theta1)
            at2 = K * s.theta1 + s.k2_ratio * K * (s.theta2 - s.theta1)
            e3 = self._segment_energy(a, s.theta2, math.inf, s.k3_ratio * K, at2)
            return e1 + e2 + e3
        return 0.5 * K * d * d

    @staticmethod
    def _segment_energy(a: float, lo: float, hi: float, slope: float, torque_at_lo: float) -> float:
        span = min(max(a - lo, 0.0), hi - lo)
        return torque_at_lo * span + 0.5 * slope * span * span

    def spring_torque(self, x: Vector) -> float:
        """Total spring torque tau_s (elastic + hysteresis elements)."""
        d = self.deflection(x)
        tau = self.spring_fn(self.region_of(d))(d)
        if self.i_z >= 0:
            tau += x[self.i_z]
        return tau + sum(x[self.i_w:self.i_w + self.n_elements])

    def net_torques(self, x: Vector, u: float) -> tuple[float, float]:
        """Net non-friction torques (motor, load)."""
        tau = self.spring_torque(x)
        T = x[self.i_lag] if self.i_lag >= 0 else u
        return T - self.gear(x[0]) * tau, tau

    # ---- per-mode right-hand side ----
    def rhs_for(self, mode: Mode) -> Callable[[Vector, float], Vector]:
        """x' = f(x, T_cmd) in ``mode`` (a closure with the mode's branches resolved; cached)."""
        fn = self._rhs_cache.get(mode)
        if fn is None:
            fn = self._rhs_cache[mode] = self._make_rhs(mode)
        return fn

    def _make_rhs(self, mode: Mode) -> Callable[[Vector, float], Vector]:
        d_, r, kin = self.drive, self.drive.r, self.effects.kinematic_error is not None
        J_m, J_l = d_.J_m, d_.J_l
        m_dir, l_dir = mode[MOTOR], mode[LOAD]
        spring, gear, kin_error = self.spring_fn(mode[2]), self.gear, self.kin_error
        f_m = self.frictions[MOTOR].sliding_fn(m_dir) if m_dir else None
        f_l = self.frictions[LOAD].sliding_fn(l_dir) if l_dir else None
        extra = self._extra_rhs(mode)
        i_lag = self.i_lag

        def rhs(x: Vector, u: float) -> Vector:
            q_m, q_l, v_m, v_l = x[0], x[1], x[2], x[3]
            g = gear(q_m) if kin else r
            d = r * q_m + (kin_error(q_m) if kin else 0.0) - q_l
            tau = spring(d)
            out = [v_m, v_l, 0.0, 0.0]
            if extra is not None:
                tau = extra(x, u, g * v_m - v_l, tau, out)
            T = x[i_lag] if i_lag >= 0 else u
            if f_m is not None:
                out[2] = (T - g * tau - f_m(v_m, q_m)) / J_m
            if f_l is not None:
                out[3] = (tau - f_l(v_l, q_m)) / J_l
            return out
        return rhs

    def _extra_rhs(self, mode: Mode) -> Callable | None:
        """The rates of the states beyond [q_m, q_l, v_m, v_l]; returns the total spring torque."""
        if self.n_states == 4:
            return None
        i_lag, i_z, i_w, n_el, i_work = self.i_lag, self.i_z, self.i_w, self.n_elements, self.i_work
        lag = self.effects.actuator_lag_s
        hyst = self.effects.hysteresis
        dahl_dir = mode[3]
        sliding = mode[4:]
        k_el = hyst.stiffnesses if isinstance(hyst, MaxwellSlip) else ()
        fr_m = self.frictions[MOTOR].sliding_fn(mode[MOTOR]) if mode[MOTOR] else None
        fr_l = self.frictions[LOAD].sliding_fn(mode[LOAD]) if mode[LOAD] else None

        def extra(x: Vector, u: float, dd: float, tau: float, out: Vector) -> float:
            if i_lag >= 0:
                out.append((u - x[i_lag]) / lag)
            hyst_torque = 0.0
            if i_z >= 0:
                z = x[i_z]
                hyst_torque = z
                out.append(_dahl_rate(z, dd, dahl_dir, hyst))
            for i in range(n_el):
                hyst_torque += x[i_w + i]
                out.append(0.0 if sliding[i] else k_el[i] * dd)
            if i_work >= 0:
                T = x[i_lag] if i_lag >= 0 else u
                v_m, v_l, q_m = x[2], x[3], x[0]
                fric = (fr_m(v_m, q_m) * v_m if fr_m else 0.0) + (fr_l(v_l, q_m) * v_l if fr_l else 0.0)
                out.extend((T * v_m, fric, hyst_torque * dd))
            return tau + hyst_torque
        return extra

    # ---- guards ----
    def guards_for(self, mode: Mode) -> tuple[list[Guard], Callable[[Vector, float], Vector]]:
        """The guards of ``mode`` (>= 0 while it holds) and a function computing their values (cached)."""
        got = self._guard_cache.get(mode)
        if got is None:
            got = self._guard_cache[mode] = self._make_guards(mode)
        return got

    def _make_guards(self, mode: Mode) -> tuple[list[Guard], Callable[[Vector, float], Vector]]:
        labels: list[Guard] = []
        parts: list[Callable[[Vector, tuple[float, float], float, float], float]] = []
        for body in (MOTOR, LOAD):
            self._body_guards(mode, body, labels, parts)
        self._region_guards(mode[2], labels, parts)
        self._hysteresis_guards(mode, labels, parts)
        r, kin = self.drive.r, self.effects.kinematic_error is not None
        spring, gear, kin_error = self.spring_fn(mode[2]), self.gear, self.kin_error
        i_lag, i_z, i_w, n_el = self.i_lag, self.i_z, self.i_w, self.n_elements

        def values(x: Vector, u: float) -> Vector:
            q_m = x[0]
            d = r * q_m + (kin_error(q_m) if kin else 0.0) - x[1]
            tau = spring(d) + (x[i_z] if i_z >= 0 else 0.0) + (sum(x[i_w:i_w + n_el]) if n_el else 0.0)
            g = gear(q_m) if kin else r
            n = ((x[i_lag] if i_lag >= 0 else u) - g * tau, tau)
            dd = g * x[2] - x[3]
            return [p(x, n, d, dd) for p in parts]
        return labels, values

    def _body_guards(self, mode: Mode, body: int, labels: list[Guard], parts: list) -> None:
        scale = (self.drive.f_m, self.drive.f_l)[body]
        if mode[body] != STUCK:
            labels.append(Guard("stop", body, (self.v_scale, self.v_scale * self.drive.r)[body]))
            parts.append(lambda x, n, d, dd, i=2 + body, s=mode[body]: s * x[i])
            return
        labels += [Guard("up", body, scale), Guard("down", body, scale)]
        fr = self.frictions[body]
        if fr.ripple is None:
            lo, hi = fr.band(0.0)
            parts += [lambda x, n, d, dd, b=body, hi=hi: hi - n[b], lambda x, n, d, dd, b=body, lo=lo: n[b] - lo]
        else:
            band = fr.band
            parts += [lambda x, n, d, dd, b=body: band(x[0])[1] - n[b],
                      lambda x, n, d, dd, b=body: n[b] - band(x[0])[0]]

    def _region_guards(self, region: int, labels: list[Guard], parts: list) -> None:
        lo, hi = self.region_bounds(region)
        if lo > -math.inf:
            labels.append(Guard("region_lo", 0, self.d_scale))
            parts.append(lambda x, n, d, dd, lo=lo: d - lo)
        if hi < math.inf:
            labels.append(Guard("region_hi", 0, self.d_scale))
            parts.append(lambda x, n, d, dd, hi=hi: hi - d)

    def _hysteresis_guards(self, mode: Mode, labels: list[Guard], parts: list) -> None:
        dd_scale = self.v_scale * self.drive.r
        if self.i_z >= 0:
            labels.append(Guard("dahl", 0, dd_scale))
            parts.append(lambda x, n, d, dd, s=mode[3]: s * dd)
        hyst = self.effects.hysteresis
        for i in range(self.n_elements):
            F, j = hyst.break_torques[i], self.i_w + i
            if mode[4 + i] == STUCK:
                labels += [Guard("w_up", i, F), Guard("w_down", i, F)]
                parts += [lambda x, n, d, dd, F=F, j=j: F - x[j], lambda x, n, d, dd, F=F, j=j: x[j] + F]
            else:
                labels.append(Guard("w_stop", i, dd_scale))
                parts.append(lambda x, n, d, dd, s=mode[4 + i]: s * dd)

    # ---- mode changes (Karnopp) ----
    def frozen(self, x: Vector, u: float, mode: Mode) -> bool:
        """Nothing can change while the command stays ``u``: both bodies stuck and the lag settled."""
        if mode[MOTOR] != STUCK or mode[LOAD] != STUCK:
            return False
        # the lag's exponential approach is taken as settled 1e-15 f_m away (it would never reach u exactly)
        return self.i_lag < 0 or abs(x[self.i_lag] - u) <= 1e-15 * self.drive.f_m

    def transition(self, x: Vector, u: float, mode: Mode, guard: Guard) -> tuple[Vector, Mode]:
        """The mode after ``guard`` reached zero at ``x`` (the crossed threshold decides the direction, so that a
        root located to round-off never makes the body stick again: no Zeno loop)."""
        x, new = list(x), list(mode)
        k, i = guard.kind, guard.index
        if k == "stop":
            x[2 + i] = 0.0
            new[i] = self._decide(x, u, i)
        elif k in ("up", "down"):
            new[i] = 1 if k == "up" else -1
        elif k in ("region_lo", "region_hi"):
            new[2] += 1 if k == "region_hi" else -1
        elif k == "dahl":
            new[3] = -new[3]
        elif k in ("w_up", "w_down"):
            x[self.i_w + i] = self.effects.hysteresis.break_torques[i] * (1 if k == "w_up" else -1)
            new[4 + i] = 1 if k == "w_up" else -1
        else:  # w_stop
            new[4 + i] = STUCK
        return x, tuple(new)

    def _decide(self, x: Vector, u: float, body: int) -> int:
        """Mode of a body at zero velocity: stuck inside its static band, else slipping along N."""
        net = self.net_torques(x, u)[body]
        lo, hi = self.frictions[body].band(x[0])
        if lo <= net <= hi:
            return STUCK
        return 1 if net > hi else -1

    def settle(self, x: Vector, u: float, mode: Mode, tol: float = 1e-9) -> tuple[Vector, Mode]:
        """Apply every transition whose guard is clearly violated (after a torque change, or an event of another
        element at the same instant) until the mode is consistent."""
        for _ in range(4 * (2 + self.n_elements) + 8):
            labels, values = self.guards_for(mode)
            bad = [(v / g.scale, g) for v, g in zip(values(x, u), labels) if v < -tol * g.scale]
            if not bad:
                return x, mode
            x, mode = self.transition(x, u, mode, min(bad, key=lambda b: b[0])[1])
        raise RuntimeError(f"no consistent mode at x = {x} (mode {mode})")

    def energy(self, x: Vector) -> float:
        """Kinetic + elastic spring energy [J]. With ``track_energy`` the works obey
        W_in = energy + W_fric + W_hyst, W_hyst being all work done on the hysteresis elements (what they store,
        ``hysteresis_stored``, plus what they dissipate)."""
        d_ = self.drive
        return 0.5 * d_.J_m * x[2] ** 2 + 0.5 * d_.J_l * x[3] ** 2 + self.spring_energy(self.deflection(x))

    def hysteresis_stored(self, x: Vector) -> float:
        """Energy held by the Maxwell-slip elements' springs [J]."""
        hyst = self.effects.hysteresis
        return sum(0.5 * x[self.i_w + i] ** 2 / hyst.stiffnesses[i] for i in range(self.n_elements))


def _dahl_rate(z: float, dd: float, direction: int, dahl: Dahl) -> float:
    """z' of the Dahl element, with the sign of dd taken from the mode (smooth within a mode)."""
    e = 1.0 - direction * z / dahl.torque
    if dahl.exponent == 1.0:
        return dahl.stiffness * dd * e
    return dahl.stiffness * dd * math.copysign(abs(e) ** dahl.exponent, e)


__all__ = [
    "LOAD",
    "MOTOR",
    "STUCK",
    "CubicStiffness",
    "Dahl",
    "Drive",
    "Effects",
    "FrictionRipple",
    "Guard",
    "HybridPlant",
    "KinematicError",
    "MaxwellSlip",
    "Stribeck",
    "ThreeSlopeStiffness",
]
