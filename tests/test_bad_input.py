"""Bad input: the FMU refuses a value outside its range with fmi2Discard / fmi3Discard (nothing changes, the
simulation can continue: the standards' suggestion for a setter's range check) and anything else it cannot do with
fmi2Error / fmi3Error (then only a reset or a saved FMU state brings it back), always with a message naming the
variable and its range; it never crashes and never puts NaN in an output; ``ident.Plant`` raises clear Python
exceptions."""
from __future__ import annotations

import ctypes
import math

import numpy as np
import pytest

from fmu_build import variables as V
from ident import DriveParams, ParameterError, Plant, PlantError

OK, DISCARD, ERROR = 0, 2, 3
REAL_PARAMS = [v for v in V.PARAMETERS if v.type == "Real"]
OUT_REALS = [v for v in V.OUTPUTS if v.type == "Real"]


class RawFMU:
    """The FMU's C functions called directly (status codes instead of exceptions), with its log captured."""

    def __init__(self, fmi: int) -> None:
        self.plant = Plant(fmi_version=fmi)  # loads and instantiates the FMU; we use its raw handles only
        self.fmi = fmi
        self.f = self.plant.fmi_functions
        self.c = self.plant.component
        self.log = self.plant.messages

    def _args(self, vrs, values, ctype):
        n = len(vrs)
        return ((ctypes.c_uint32 * n)(*vrs), n, (ctype * n)(*values)) + ((n,) if self.fmi == 3 else ())

    def set_real(self, vrs, values) -> int:
        fn = self.f["fmi2SetReal" if self.fmi == 2 else "fmi3SetFloat64"]
        return fn(self.c, *self._args(vrs, values, ctypes.c_double))

    def set_int(self, vrs, values) -> int:
        fn = self.f["fmi2SetInteger" if self.fmi == 2 else "fmi3SetInt32"]
        return fn(self.c, *self._args(vrs, values, ctypes.c_int32))

    def get_reals(self) -> tuple[int, list[float]]:
        vrs = [v.vr for v in OUT_REALS]
        n = len(vrs)
        out = (ctypes.c_double * n)()
        fn = self.f["fmi2GetReal" if self.fmi == 2 else "fmi3GetFloat64"]
        args = ((ctypes.c_uint32 * n)(*vrs), n, out) + ((n,) if self.fmi == 3 else ())
        return fn(self.c, *args), list(out)

    def reset(self) -> int:
        return self.f["fmi2Reset" if self.fmi == 2 else "fmi3Reset"](self.c)

    def initialize(self) -> int:
        if self.fmi == 2:
            s = self.f["fmi2SetupExperiment"](self.c, 0, 0.0, 0.0, 0, 0.0)
            s = max(s, self.f["fmi2EnterInitializationMode"](self.c))
            return max(s, self.f["fmi2ExitInitializationMode"](self.c))
        s = self.f["fmi3EnterInitializationMode"](self.c, False, 0.0, 0.0, False, 0.0)
        return max(s, self.f["fmi3ExitInitializationMode"](self.c))

    def do_step(self, t: float, h: float) -> int:
        if self.fmi == 2:
            return self.f["fmi2DoStep"](self.c, t, h, 1)
        flags = [ctypes.c_bool() for _ in range(3)]
        last = ctypes.c_double()
        return self.f["fmi3DoStep"](self.c, t, h, True, *map(ctypes.byref, flags), ctypes.byref(last))


@pytest.fixture(params=[2, 3], ids=["fmi2", "fmi3"])
def raw(request) -> RawFMU:
    fmu = RawFMU(request.param)
    fmu.reset()
    yield fmu
    fmu.plant.close()


@pytest.mark.parametrize("name,value", [("J_m", 0.0), ("J_m", -2e-5), ("J_l", 0.0), ("K_s", -1.0), ("K_s", 0.0),
                                        ("r", 0.0), ("r", -0.01), ("f_m", -0.01), ("f_l", -1e-3),
                                        ("J_l", math.nan), ("arm_length", math.inf)])
def test_unphysical_parameter_is_an_error_naming_variable_and_range(raw: RawFMU, name: str, value: float) -> None:
    var = V.BY_NAME[name]
    raw.log.clear()
    assert raw.set_real([var.vr], [value]) == DISCARD
    assert raw.log, "the FMU logged nothing"
    msg = raw.log[-1]
    assert name in msg and "allowed range" in msg and f"{var.lo:g}" in msg and f"{var.hi:g}" in msg, msg
    assert raw.initialize() == OK  # the bad value was not taken: the nominal drive initializes
    status, outs = raw.get_reals()
    assert status == OK and all(math.isfinite(x) for x in outs)


def test_bad_encoder_counts(raw: RawFMU) -> None:
    raw.log.clear()
    assert raw.set_int([V.BY_NAME["encoder_counts_per_rev"].vr], [0]) == DISCARD
    assert "encoder_counts_per_rev" in raw.log[-1]


@pytest.mark.parametrize("torque", [math.nan, math.inf, -math.inf])
def test_non_finite_torque_is_an_error(raw: RawFMU, torque: float) -> None:
    assert raw.initialize() == OK
    raw.log.clear()
    assert raw.set_real([V.BY_NAME["motor_torque"].vr], [torque]) == DISCARD
    assert "motor_torque" in raw.log[-1]
    assert raw.do_step(0.0, 1e-3) == OK  # the previous (valid) torque is still held
    status, outs = raw.get_reals()
    assert all(math.isfinite(x) for x in outs)


def test_bad_step_size_is_an_error(raw: RawFMU) -> None:
    for h in (-1e-3, math.nan, math.inf):
        assert raw.reset() == OK and raw.initialize() == OK
        raw.log.clear()
        assert raw.do_step(0.0, h) == ERROR
        assert "step size" in raw.log[-1]
        assert raw.do_step(0.0, 1e-3) == ERROR  # the error state: only a reset (or a saved state) continues
        assert "must not be called" in raw.log[-1]


def test_parameters_cannot_change_after_initialization(raw: RawFMU) -> None:
    assert raw.initialize() == OK
    raw.log.clear()
    assert raw.set_real([V.BY_NAME["K_s"].vr], [2e4]) == ERROR
    assert "must not be called" in raw.log[-1]


def test_plant_raises_clear_python_errors() -> None:
    with pytest.raises(ParameterError, match=r"J_m = -1 kg.m2 is outside the allowed range \[1e-12, 1000\]"):
        DriveParams(J_m=-1)
    with pytest.raises(ParameterError, match="unknown drive parameter 'K'"):
        DriveParams().with_values(K=3)
    with pytest.raises(ParameterError, match="K_star"):
        DriveParams.from_nondim(K_star=math.nan, J_l_star=2500, f_l_star=0.1)
    with Plant() as plant:
        with pytest.raises(PlantError, match="motor_torque = nan"):
            plant.step(math.nan, 1e-3)
        with pytest.raises(PlantError, match="step size"):
            plant.step(0.0, -1.0)
        with pytest.raises(ParameterError, match="q_m_start"):
            plant.reset(q_m_start=math.inf)
        s = plant.step(0.03, 1e-3)  # still usable after the errors
        assert math.isfinite(s.q_m) and s.q_m > 0


def _random_value(rng: np.random.Generator, var: V.Variable) -> tuple[float, bool]:
    """A value for a parameter: mostly valid (log-uniform near the nominal drive, inside the variable's range),
    sometimes unphysical."""
    u = rng.random()
    if u < 0.04:
        bad = [math.nan, math.inf, -math.inf, var.lo - max(1.0, abs(var.lo)), var.hi * 10] + ([0.0] if var.lo > 0 else [])
        return float(rng.choice(bad)), False
    if var.name.endswith("_start"):
        scale = 1e-4 if var.name.startswith("q") else 1e-1
        return float(rng.uniform(-scale, scale)), True
    if var.name in ("f_m", "f_l") and u < 0.08:
        return 0.0, True
    value = float(var.start * 10 ** rng.uniform(-2, 2)) if var.name != "r" else float(10 ** rng.uniform(-3, 0))
    if not var.lo <= value <= var.hi:   # a range narrower than four decades (an exponent): uniform inside it
        value = float(rng.uniform(var.lo, var.hi))
    return value, True


def test_random_parameters_inputs_and_steps_never_crash_or_nan() -> None:
    """10,000 random parameter sets, torques and step sizes through both FMUs: either the call succeeds with
    finite outputs, or it is refused with fmiError and a message; nothing in between."""
    rng = np.random.default_rng(20261122)
    fmus = {2: RawFMU(2), 3: RawFMU(3)}
    refused = stepped = 0
    for case in range(10_000):
        fmu = fmus[2 if case % 2 == 0 else 3]
        assert fmu.reset() == OK
        valid = True
        for var in REAL_PARAMS:
            value, ok = _random_value(rng, var)
            fmu.log.clear()
            status = fmu.set_real([var.vr], [value])
            assert status == (OK if ok else DISCARD), (case, var.name, value, fmu.log)
            if not ok:
                assert var.name in fmu.log[-1]
                refused += 1
            valid &= ok
        assert fmu.initialize() == OK
        f_m = V.BY_NAME["f_m"].start
        t = 0.0
        for _ in range(3):
            torque = float(rng.choice([math.nan, math.inf])) if rng.random() < 0.03 else \
                float(rng.uniform(-5, 5) * f_m * 10 ** rng.uniform(-1, 1))
            status = fmu.set_real([V.BY_NAME["motor_torque"].vr], [torque])
            assert status == (OK if math.isfinite(torque) else DISCARD)
            h = float(10 ** rng.uniform(-6, -1))
            status = fmu.do_step(t, h)
            assert status == OK, (case, fmu.log[-1:] )
            t += h
            stepped += 1
            status, outs = fmu.get_reals()
            assert status == OK and all(math.isfinite(x) for x in outs), (case, outs)
    for f in fmus.values():
        f.plant.close()
    assert refused > 100 and stepped == 30_000
