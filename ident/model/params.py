"""Drive parameters: SI values, the paper's non-dimensional groups, validation, the nominal drive.

Names, units, start values and allowed ranges come from the FMU's variable table (``fmu_build.variables``), so the
Python side and the C side can never disagree on what a valid drive is.

Non-dimensional groups (paper eqs 7-18): T_c = sqrt(J_m/f_m) [s], K* = K_s/f_m [1/rad], J_l* = J_l/J_m,
f_l* = f_l/f_m, tau* = T_m/f_m, r* = r.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

from fmu_build import variables as V

from .effects import KINEMATIC_ERROR_PARAMS, kinematic_error


class ParameterError(ValueError):
    """A drive parameter is unknown, not a finite number, or outside its allowed range."""


def check_parameter(name: str, value: Any) -> float | int:
    """Validate one FMU parameter by name against the variable table; returns the value as float (or int)."""
    var = V.BY_NAME.get(name)
    if var is None or var.causality != "parameter":
        known = ", ".join(v.name for v in V.PARAMETERS)
        raise ParameterError(f"unknown drive parameter {name!r}; known parameters: {known}")
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise ParameterError(f"{name} = {value!r} is not a number") from None
    if not (var.lo <= number <= var.hi):  # also rejects NaN
        unit = f" {var.unit}" if var.unit not in (None, "1") else ""
        raise ParameterError(f"{name} = {value!r}{unit} is outside the allowed range [{var.lo:g}, {var.hi:g}]{unit}")
    if var.type == "Integer":
        if number != int(number):
            raise ParameterError(f"{name} = {value!r} must be a whole number")
        return int(number)
    return number


@dataclass(frozen=True)
class DriveParams:
    """SI parameters of one harmonic-drive joint. Defaults are the nominal drive of physics.md section 2."""

    J_m: float = V.BY_NAME["J_m"].start       # kg m^2, motor + wave generator
    f_m: float = V.BY_NAME["f_m"].start       # N m, motor Coulomb = static friction
    K_s: float = V.BY_NAME["K_s"].start       # N m/rad, torsional stiffness (load side)
    J_l: float = V.BY_NAME["J_l"].start       # kg m^2, flexspline + arm
    f_l: float = V.BY_NAME["f_l"].start       # N m, load Coulomb = static friction
    r: float = V.BY_NAME["r"].start           # gear ratio q_l/q_m (< 1)
    encoder_counts_per_rev: int = V.BY_NAME["encoder_counts_per_rev"].start
    arm_length: float = V.BY_NAME["arm_length"].start  # m
    # Optional effects of the discrepancy library (physics.md section 5); the defaults switch every effect off.
    b_m: float = V.BY_NAME["b_m"].start                      # N m s/rad, motor viscous friction
    b_l: float = V.BY_NAME["b_l"].start                      # N m s/rad, load viscous friction
    stribeck_ratio: float = V.BY_NAME["stribeck_ratio"].start  # static / Coulomb level - 1
    stribeck_velocity: float = V.BY_NAME["stribeck_velocity"].start  # rad/s, load side (motor: / r)
    friction_asymmetry: float = V.BY_NAME["friction_asymmetry"].start  # levels f (1 +- a) for +- motion
    hardening: float = V.BY_NAME["hardening"].start          # 1/rad^2, spring K_s (d + hardening d^3)
    hysteresis_torque: float = V.BY_NAME["hysteresis_torque"].start  # N m, Dahl saturation torque H (0 = off)
    hysteresis_stiffness: float = V.BY_NAME["hysteresis_stiffness"].start  # N m/rad, Dahl initial stiffness
    kinematic_error: float = V.BY_NAME["kinematic_error"].start  # rad, transmission error amplitude (load side)
    kinematic_error_phase: float = V.BY_NAME["kinematic_error_phase"].start  # rad
    viscous_asymmetry: float = V.BY_NAME["viscous_asymmetry"].start  # viscous coefficients b (1 +- a_v) for +- motion
    kinematic_error_4: float = V.BY_NAME["kinematic_error_4"].start  # rad, its 4/rev harmonic (load side)
    kinematic_error_4_phase: float = V.BY_NAME["kinematic_error_4_phase"].start  # rad
    stribeck_shape: float = V.BY_NAME["stribeck_shape"].start  # exponent delta of the decay: 2 Gaussian, 1 exponential
    hysteresis_exponent: float = V.BY_NAME["hysteresis_exponent"].start  # Dahl exponent n (1: the classic element)
    hardening_exponent: float = V.BY_NAME["hardening_exponent"].start  # p: K_s (d + h d |d|^p d_h^(2-p)); 2: cubic
    hardening_deflection: float = V.BY_NAME["hardening_deflection"].start  # rad, d_h (no effect at p = 2)

    def __post_init__(self) -> None:
        for name in FIELD_NAMES:
            object.__setattr__(self, name, check_parameter(name, getattr(self, name)))

    # -- non-dimensional view -------------------------------------------------------------------------------
    def _f_m_for(self, group: str) -> float:
        """f_m, the scale of every non-dimensional group; ParameterError when it cannot be one (f_m = 0)."""
        if self.f_m <= 0:
            raise ParameterError(f"f_m must be > 0 for {group} (the paper's groups are scaled by the motor's Coulomb "
                                 f"friction), got f_m = {self.f_m!r} N.m")
        return self.f_m

    @property
    def T_c(self) -> float:
        """Characteristic time sqrt(J_m/f_m) [s] (needs f_m > 0)."""
        return math.sqrt(self.J_m / self._f_m_for("T_c = sqrt(J_m/f_m)"))

    @property
    def K_star(self) -> float:
        return self.K_s / self._f_m_for("K* = K_s/f_m")

    @property
    def J_l_star(self) -> float:
        return self.J_l / self.J_m

    @property
    def f_l_star(self) -> float:
        return self.f_l / self._f_m_for("f_l* = f_l/f_m")

    @property
    def count_rad(self) -> float:
        """One motor encoder count [rad of motor angle]."""
        return 2.0 * math.pi / self.encoder_counts_per_rev

    @property
    def count_at_arm_m(self) -> float:
        """One motor encoder count seen at the arm tip [m] (1.50 µm on the nominal drive)."""
        return self.count_rad * self.r * self.arm_length

    def load_angle_at(self, q_m: float, twist: float = 0.0) -> float:
        """The load angle [rad] at which the spring's twist is ``twist`` with the motor at ``q_m``:
        r q_m + e(q_m) - twist, e the kinematic error (``ident.model.effects``). A simulation that starts a log at
        rest places the load here: without e(q_m) a kinematic error would start it twisted by e(q_m), which can lie
        well outside the static band a log at rest must start in."""
        e = float(kinematic_error(q_m, tuple(getattr(self, k) for k in KINEMATIC_ERROR_PARAMS)))
        return self.r * q_m + e - twist

    @classmethod
    def nominal(cls) -> "DriveParams":
        return cls()

    @classmethod
    def from_nondim(cls, K_star: float, J_l_star: float, f_l_star: float, *, J_m: float | None = None,
                    f_m: float | None = None, **si: Any) -> "DriveParams":
        """Build from K*, J_l*, f_l* with the motor's J_m and f_m given (nominal ones by default)."""
        J_m = cls.J_m if J_m is None else J_m
        f_m = cls.f_m if f_m is None else f_m
        if not (isinstance(f_m, (int, float)) and f_m > 0):
            raise ParameterError(f"f_m = {f_m!r} N.m: K*, J_l*, f_l* are scaled by f_m, which must be > 0")
        for name, value in (("K_star", K_star), ("J_l_star", J_l_star), ("f_l_star", f_l_star)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ParameterError(f"{name} = {value!r} must be a finite number >= 0")
        return cls(J_m=J_m, f_m=f_m, K_s=K_star * f_m, J_l=J_l_star * J_m, f_l=f_l_star * f_m, **si)

    def with_values(self, **changes: Any) -> "DriveParams":
        """A copy with some SI parameters or non-dimensional groups (K_star, J_l_star, f_l_star) changed."""
        nondim = {k: changes.pop(k) for k in ("K_star", "J_l_star", "f_l_star") if k in changes}
        unknown = set(changes).difference(FIELD_NAMES)
        if unknown:
            check_parameter(sorted(unknown)[0], 0.0)  # raises with the list of known names
        p = self._changed(changes)
        if nondim:
            f_m, J_m = p._f_m_for(", ".join(nondim)), p.J_m
            p = p._changed({"K_s": nondim.get("K_star", p.K_star) * f_m,
                            "J_l": nondim.get("J_l_star", p.J_l_star) * J_m,
                            "f_l": nondim.get("f_l_star", p.f_l_star) * f_m})
        return p

    def _changed(self, changes: dict[str, Any]) -> "DriveParams":
        """A copy with ``changes`` (known names), each checked as the constructor checks it; the other fields are
        this object's, checked when it was made, so they are copied, not checked again. Why: a fit makes one
        ``DriveParams`` per simulation, and with all 23 fields checked again that cost 0.044 ms (0.006-0.011 ms now),
        beside the 0.6 ms a 4 s identification log's fit window simulates in. Without changes, this object (frozen:
        a copy would be equal)."""
        if not changes:
            return self
        new = object.__new__(type(self))
        values = new.__dict__   # frozen: the fields are written the way ``__post_init__`` writes them, past __setattr__
        values.update(self.__dict__)
        for name, value in changes.items():
            values[name] = check_parameter(name, value)
        return new

    def to_dict(self) -> dict[str, float | int]:
        """Every parameter by name, in the table's order. Every field is a number, so no copy is needed (the
        plant's reset and the simulation memo's key read it once per simulation: ``asdict`` deep-copied each field,
        about 0.05 ms of a 3 s log's 2.5 ms simulation)."""
        return {name: getattr(self, name) for name in FIELD_NAMES}


#: the parameters' names in the table's order, as ``to_dict`` gives them (read per simulation: ``dataclasses.fields``
#: rebuilds them per call)
FIELD_NAMES = tuple(f.name for f in fields(DriveParams))


def parse_assignments(items: list[str] | None) -> dict[str, float]:
    """Parse CLI ``NAME=VALUE`` items; NAME may be an SI parameter or K_star / J_l_star / f_l_star."""
    out: dict[str, float] = {}
    for item in items or []:
        name, sep, value = item.partition("=")
        if not sep:
            raise ParameterError(f"--param expects NAME=VALUE, got {item!r}")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise ParameterError(f"--param {name.strip()}: {value!r} is not a number") from None
    return out
