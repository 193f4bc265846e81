"""Controllers of the resolution study (physics.md section 3). They speak only to a ``Plant`` (never to fmpy).

- ``ImpulseController``: one torque pulse tau* = A for ``width_s``, then zero torque until the plant is at rest.
- ``LinearPD``: PD on the quantized motor encoder, sampled, zero-order hold, derivative on the measurement,
  saturated; usable in any user loop (``control(sample) -> torque``) or step by step (``move(plant, counts)``).

Both are exact with respect to the plant: the FMU locates every stick-slip event inside a communication step, so
the state at a communication point does not depend on the step size. The impulse controller therefore waits for
rest with large steps; the PD controller steps at its own sampling period (its output changes only there).

These are the controllers for loops you write around a ``Plant``. The protocols (``ident.protocols.resolution``) run
the same ``pulse`` / ``move`` loops compiled by default (``ident.protocols.compiled``, bit for bit the same results);
``loop="python"`` makes them use the classes here.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from ..common.checks import number, whole
from ..model.params import DriveParams
from ..model.plant import SettleError

if TYPE_CHECKING:  # pragma: no cover
    from ..model.plant import Plant, Sample


class ImpulseController:
    """Open-loop impulse controller: tau* = ``amplitude_star`` (torque = A f_m) for ``width_s``, then zero torque
    until both bodies are stuck.

    ``rest_step_s`` is the communication step used while waiting for rest; since the FMU is event-exact, its value
    changes only how often ``at_rest`` is polled, never the result. ``max_rest_s`` guards the wait.
    """

    def __init__(self, amplitude_star: float, width_s: float = 1e-3, *, rest_step_s: float = 0.02,
                 max_rest_s: float = 60.0) -> None:
        self.amplitude_star = number("amplitude_star", amplitude_star)
        self.width_s = number("width_s", width_s, positive=True)
        self.rest_step_s = number("rest_step_s", rest_step_s, positive=True)
        self.max_rest_s = number("max_rest_s", max_rest_s, positive=True)

    def to_rest(self, plant: "Plant") -> "Sample":
        """Zero torque until the plant is at rest under zero torque (``Plant.run_to_rest``)."""
        return plant.run_to_rest(self.rest_step_s, self.max_rest_s)

    def pulse(self, plant: "Plant") -> float:
        """One pulse from rest to rest; returns the arm increment [m] between the two rests.

        If the plant is not at rest under zero torque when called, it is first brought there (the increment is
        counted from that rest).
        """
        s = plant.sample()
        if not (s.at_rest and plant.torque == 0.0):
            s = self.to_rest(plant)
        before = s.arm_position
        plant.step(self.amplitude_star * plant.params.f_m, self.width_s)
        return self.to_rest(plant).arm_position - before


class LinearPD:
    """PD controller on the quantized motor encoder (paper section III, physics.md section 3).

    Measurement y = encoder_count * count_rad [rad of motor angle]; set-point angle = setpoint_count * count_rad.
    At every sample (period 1/rate_hz, zero-order hold in between)::

        u* = Kp* (set-point - y) - Kd* (y_k - y_{k-1}) / dt*        dt* = (1/rate_hz) / T_c
        u* = clip(u*, -saturation*, +saturation*)                    torque = u* f_m  [N m]

    The derivative acts on the measurement (no kick when the set-point steps); the first sample after ``reset``
    has a zero derivative.

    In a user loop::

        pd = LinearPD(params=plant.params); pd.reset(sample=plant.sample())
        pd.setpoint_count += 5
        s = plant.sample()
        for _ in range(n):
            s = plant.step(pd.control(s), pd.dt_s)

    Call ``reset`` again whenever the plant is reset.
    """

    def __init__(self, Kp_star: float = 200.0, Kd_star: float = 19.2, rate_hz: float = 1000.0,
                 saturation_star: float = 20.0, *, params: DriveParams | None = None) -> None:
        self.Kp_star = number("Kp_star", Kp_star)
        self.Kd_star = number("Kd_star", Kd_star)
        self.rate_hz = number("rate_hz", rate_hz, positive=True)
        self.saturation_star = number("saturation_star", saturation_star, positive=True)
        self.params: DriveParams | None = None
        self.setpoint_count = 0
        self._y_prev: float | None = None
        self._count_prev: int | None = None
        self.last_torque = 0.0
        self.last_derivative_zero = True
        if params is not None:
            self.reset(params)

    @property
    def dt_s(self) -> float:
        """Sampling period [s]."""
        return 1.0 / self.rate_hz

    def reset(self, params: DriveParams | None = None, sample: "Sample | None" = None,
              setpoint_count: int | None = None) -> None:
        """Bind to a drive and forget the past. With ``sample`` the derivative memory starts at its encoder count
        and the set-point defaults to it (else to 0)."""
        if params is not None:
            if not isinstance(params, DriveParams):
                raise TypeError(f"params must be a DriveParams, got {type(params).__name__}")
            self.params = params
        if self.params is None:
            raise ValueError("LinearPD needs the drive parameters: reset(params) or LinearPD(params=...)")
        self._T_c = self.params.T_c
        self._count_rad = self.params.count_rad
        self._f_m = self.params.f_m
        self._dt_star = self.dt_s / self._T_c
        self._count_prev = None if sample is None else int(sample.encoder_count)
        if setpoint_count is not None:
            self.setpoint_count = int(setpoint_count)
        else:
            self.setpoint_count = 0 if sample is None else int(sample.encoder_count)
        self.last_torque = 0.0
        self.last_derivative_zero = True

    def control(self, sample: "Sample") -> float:
        """The torque [N m] to hold for the next period, from the sample taken now."""
        if self.params is None:
            raise ValueError("LinearPD is not bound to a drive: call reset(params) first")
        count = int(sample.encoder_count)
        prev = count if self._count_prev is None else self._count_prev
        self._count_prev = count
        y = count * self._count_rad
        e = self.setpoint_count * self._count_rad - y
        dcount = count - prev
        u = self.Kp_star * e - self.Kd_star * (dcount * self._count_rad) / self._dt_star
        u = min(self.saturation_star, max(-self.saturation_star, u))
        self.last_derivative_zero = dcount == 0
        self.last_torque = u * self._f_m
        return self.last_torque

    def move(self, plant: "Plant", counts: int, *, max_time_s: float = 10.0) -> float:
        """Step the set-point by ``counts`` and run until nothing can move again; return the arm increment [m].

        Final-rest rule (exact, not a tolerance): at a sample where both bodies are stuck at the end of the last
        period, the encoder count equals the previous sample's (derivative term zero) and the new controller
        output equals the torque that was held during that period, nothing can move again: the bodies stay stuck
        under an unchanged torque, so the count, hence the output, never changes. ``SettleError`` if this does
        not happen within ``max_time_s`` (a limit cycle). The controller is (re)bound to the plant's drive if it
        is not bound to it yet.
        """
        counts = whole("counts", counts, -2**31)
        s = plant.sample()
        if self.params is None or self.params != plant.params:
            self.reset(plant.params, s)
        start = s.arm_position
        self.setpoint_count += int(counts)
        held = plant.torque
        dt = self.dt_s
        t_end = plant.time + max_time_s
        while True:
            u = self.control(s)
            if s.at_rest and self.last_derivative_zero and u == held:
                return s.arm_position - start
            if plant.time > t_end:
                raise SettleError(f"LinearPD.move({counts}) did not settle within {max_time_s} s "
                                  f"(encoder {s.encoder_count}, set-point {self.setpoint_count})")
            s = plant.step(u, dt)
            held = u
