"""THE variable table of the HarmonicDrive plant.

Every other description of the plant's interface is generated from or checked against this table:
both modelDescription.xml files (FMI 2.0 and 3.0), the C header ``model_vars.h`` that the C model and the FMI
glue use for value references, start values and allowed ranges, the parameter handling of ``ident.model.params``, and
the test that holds ``modelica/HarmonicDrive`` to the same names, units and start values.

All values are SI; time is in seconds. The nominal drive of ``shared/docs/physics.md`` section 2 gives the start
values (f_l = f_l* f_m = 0.1 * 0.01 N m).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

VarType = Literal["Real", "Integer", "Boolean"]
Causality = Literal["independent", "parameter", "input", "output", "local"]

INT32_MAX = 2**31 - 1


@dataclass(frozen=True)
class Variable:
    """One FMU variable. ``lo``/``hi`` are the allowed (inclusive) range checked by the FMU and by Python."""

    name: str
    vr: int
    type: VarType
    causality: Causality
    unit: str | None
    start: float | int | bool | None
    lo: float | None
    hi: float | None
    description: str


def _param(name: str, vr: int, start: float, lo: float, hi: float, unit: str | None, desc: str,
           type_: VarType = "Real") -> Variable:
    return Variable(name, vr, type_, "parameter", unit, start, lo, hi, desc)


def _out(name: str, vr: int, unit: str | None, desc: str, type_: VarType = "Real") -> Variable:
    return Variable(name, vr, type_, "output", unit, None, None, None, desc)


def _local(name: str, vr: int, unit: str | None, desc: str) -> Variable:
    return Variable(name, vr, "Real", "local", unit, None, None, None, desc)


# Value references: 0 time, 1-19 drive parameters, 20-29 initial state, 30 input, 40-59 outputs, 60-69 locals,
# 100+ reserved for the optional effect parameters of the discrepancy library (default off).
VARIABLES: tuple[Variable, ...] = (
    Variable("time", 0, "Real", "independent", "s", None, None, None, "Simulation time"),
    _param("J_m", 1, 2e-5, 1e-12, 1e3, "kg.m2", "Motor + wave-generator inertia"),
    _param("f_m", 2, 0.01, 0.0, 1e6, "N.m", "Motor-side Coulomb (= static) friction level"),
    _param("K_s", 3, 1.0e4, 1e-3, 1e15, "N.m/rad", "Torsional stiffness of the flexspline (load side)"),
    _param("J_l", 4, 0.05, 1e-12, 1e6, "kg.m2", "Flexspline + arm inertia"),
    _param("f_l", 5, 1e-3, 0.0, 1e6, "N.m", "Load-side Coulomb (= static) friction level"),
    _param("r", 6, 0.01, 1e-6, 1.0, "1", "Gear ratio q_l/q_m at rest (r < 1: 0.01 is a 100:1 drive)"),
    _param("encoder_counts_per_rev", 7, 12566, 1, INT32_MAX, None, "Motor encoder counts per motor revolution",
           type_="Integer"),
    _param("arm_length", 8, 0.3, 1e-6, 1e3, "m", "Arm length: arm_position = arm_length * q_l"),
    _param("q_m_start", 20, 0.0, -1e6, 1e6, "rad", "Initial motor angle"),
    _param("q_l_start", 21, 0.0, -1e6, 1e6, "rad", "Initial load angle"),
    _param("v_m_start", 22, 0.0, -1e6, 1e6, "rad/s", "Initial motor velocity"),
    _param("v_l_start", 23, 0.0, -1e6, 1e6, "rad/s", "Initial load velocity"),
    Variable("motor_torque", 30, "Real", "input", "N.m", 0.0, -1e6, 1e6,
             "Motor torque T_m, held constant over each communication step"),
    _out("q_m", 40, "rad", "Motor angle"),
    _out("q_l", 41, "rad", "Load (arm) angle"),
    _out("v_m", 42, "rad/s", "Motor velocity"),
    _out("v_l", 43, "rad/s", "Load velocity"),
    _out("spring_torque", 44, "N.m", "Total transmitted torque on the load: K_s (d + hardening d^3) + hysteresis_state"),
    _out("motor_stuck", 45, None, "Motor is stuck (zero velocity, net torque within its static level)", "Boolean"),
    _out("load_stuck", 46, None, "Load is stuck (zero velocity, net torque within its static level)", "Boolean"),
    _out("encoder_count", 47, None, "Motor encoder count floor(q_m / (2 pi / counts_per_rev)), saturated to int32",
         "Integer"),
    _out("arm_position", 48, "m", "Arm tip position arm_length * q_l"),
    _out("input_work", 49, "J", "Work done by the motor torque since the start (exact per segment)"),
    _out("friction_work", 50, "J", "Energy dissipated by friction since the start (exact per segment)"),
    _out("deflection", 51, "rad", "Spring deflection d = r q_m + e(q_m) - q_l (load side), e the kinematic error"),
    _out("hysteresis_state", 52, "N.m", "Torque z of the Dahl hysteresis element (0 when hysteresis_torque = 0)"),
    _out("motor_friction_torque", 53, "N.m",
         "Friction torque F_m on the motor (J_m v_m' = T - g tau_s - F_m); while stuck, the holding reaction"),
    _out("load_friction_torque", 54, "N.m",
         "Friction torque F_l on the load (J_l v_l' = tau_s - F_l); while stuck, the holding reaction"),
    # Not physics: the solver's work, readable (fmiGet) but no output to connect; the Modelica twin has none.
    _local("model_evaluations", 60, None,
           "Evaluations of the model's equations done by the doSteps since initialization (the unit of the per-step "
           "work budget): what a simulation cost, counted the same on any machine"),
    # Optional effects of the discrepancy library (physics.md section 5). Every start value switches its effect
    # off; with all of them off the plant is the base model above, solved in closed form.
    _param("b_m", 100, 0.0, 0.0, 1e6, "N.m.s/rad", "Motor viscous friction coefficient"),
    _param("b_l", 101, 0.0, 0.0, 1e6, "N.m.s/rad", "Load viscous friction coefficient"),
    _param("stribeck_ratio", 102, 0.0, 0.0, 10.0, "1",
           "Static level / Coulomb level - 1 (both bodies): Stribeck friction f (1 + s exp(-|v/vs|^delta))"),
    _param("stribeck_velocity", 103, 1e-3, 1e-12, 1e6, "rad/s",
           "Stribeck velocity vs on the load side; the motor uses stribeck_velocity / r"),
    _param("friction_asymmetry", 104, 0.0, -0.99, 0.99, "1",
           "Friction levels are f (1 + a) for positive and f (1 - a) for negative motion (both bodies)"),
    _param("hardening", 105, 0.0, 0.0, 1e20, "1/rad2", "K3/K_s: spring torque K_s (d + hardening d^3)"),
    _param("hysteresis_torque", 106, 0.0, 0.0, 1e6, "N.m",
           "Saturation torque H of a Dahl hysteresis element in parallel with the spring (0 = off)"),
    _param("hysteresis_stiffness", 107, 1.0e4, 1e-3, 1e15, "N.m/rad", "Initial stiffness sigma of the Dahl element"),
    _param("kinematic_error", 108, 0.0, 0.0, 1.0, "rad",
           "Amplitude A of the transmission error (load side), twice per wave-generator turn: e(q_m) = "
           "A sin(2 q_m + phi) + A4 sin(4 q_m + phi4)"),
    _param("kinematic_error_phase", 109, 0.0, -10.0, 10.0, "rad", "Phase phi of the transmission error"),
    _param("viscous_asymmetry", 110, 0.0, -0.99, 0.99, "1",
           "Viscous coefficients are b (1 + a_v) for positive and b (1 - a_v) for negative motion (both bodies)"),
    _param("kinematic_error_4", 111, 0.0, 0.0, 1.0, "rad",
           "Amplitude A4 of the transmission error's second harmonic, four times per wave-generator turn"),
    _param("kinematic_error_4_phase", 112, 0.0, -10.0, 10.0, "rad", "Phase phi4 of the second harmonic"),
    _param("stribeck_shape", 113, 2.0, 1.0, 4.0, "1",
           "Exponent delta of the Stribeck decay exp(-|v/vs|^delta): 2 Gaussian (the default), 1 exponential"),
    _param("hysteresis_exponent", 114, 1.0, 1.0, 4.0, "1",
           "Exponent n of the Dahl element z' = sigma dd |1 - sgn(dd) z/H|^n sgn(1 - sgn(dd) z/H): 1 the classic "
           "Dahl (the default), larger a slower, algebraic approach to H"),
    _param("hardening_exponent", 115, 2.0, 1.0, 4.0, "1",
           "Exponent p of the hardening: spring torque K_s (d + hardening d |d|^p hardening_deflection^(2 - p)); 2 the "
           "cubic (the default), 1 a stiffening that grows with |d| rather than d^2"),
    _param("hardening_deflection", 116, 1.0, 1e-12, 1e3, "rad",
           "Deflection at which a hardening of exponent p != 2 stiffens as the cubic of the same hardening does (no "
           "effect at p = 2)"),
)

BY_NAME: dict[str, Variable] = {v.name: v for v in VARIABLES}
PARAMETERS: tuple[Variable, ...] = tuple(v for v in VARIABLES if v.causality == "parameter")
INPUTS: tuple[Variable, ...] = tuple(v for v in VARIABLES if v.causality == "input")
OUTPUTS: tuple[Variable, ...] = tuple(v for v in VARIABLES if v.causality == "output")

# Base units of every unit used in the table, for the <UnitDefinitions> of both modelDescriptions.
UNITS: dict[str, dict[str, int]] = {
    "s": {"s": 1},
    "rad": {"rad": 1},
    "rad/s": {"rad": 1, "s": -1},
    "N.m": {"kg": 1, "m": 2, "s": -2},
    "N.m/rad": {"kg": 1, "m": 2, "s": -2, "rad": -1},
    "kg.m2": {"kg": 1, "m": 2},
    "m": {"m": 1},
    "J": {"kg": 1, "m": 2, "s": -2},
    "N.m.s/rad": {"kg": 1, "m": 2, "s": -1, "rad": -1},
    "1/rad2": {"rad": -2},
    "1": {},
}



@dataclass(frozen=True)
class LogCategory:
    """One log category of the FMU (the ``<LogCategories>`` of both modelDescriptions and the C glue's table).

    ``default``: enabled by ``loggingOn = true`` at instantiation (FMI 3: "categories for messages that explain
    execution errors, like fmi3Discard, fmi3Error"); the others only through ``fmiXSetDebugLogging``.
    """

    name: str
    description: str
    default: bool


LOG_CATEGORIES: tuple[LogCategory, ...] = (
    LogCategory("logStatusError", "Why a call returned Error: the variable and its allowed range, the step that "
                "cannot be computed, a call the current state does not allow, an invalid FMU state", True),
    LogCategory("logStatusDiscard", "Why a setter returned Discard: a parameter or input value outside its allowed "
                "range (the value is not taken; the simulation can continue)", True),
    LogCategory("logSteps", "One line per doStep: its step size, the switching events handled and the model "
                "evaluations spent of the per-step work budget", False),
)

MODEL_IDENTIFIER = "HarmonicDrive"
MODEL_NAME = "HarmonicDrive"
AUTHOR = "hdrive contributors"
