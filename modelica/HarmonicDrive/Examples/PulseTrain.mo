within HarmonicDrive.Examples;
model PulseTrain "The nominal drive driven by a train of 1 ms motor torque pulses (open-loop impulse control)"
  parameter Real amplitude(unit = "1") = 2.0 "Pulse amplitude tau* = T_m/f_m";
  parameter Real width(unit = "s") = 1e-3 "Pulse width W";
  parameter Real period(unit = "s") = 0.25 "Pulse period (long enough for both bodies to come to rest)";
  parameter Integer n_pulses = 4 "Number of pulses";
  HarmonicDrive.Plant plant "The nominal drive";
  Real arm_position_um(unit = "1") "Arm tip position in micrometres";
equation
  plant.motor_torque = if time < n_pulses*period and time - period*floor(time/period) < width then amplitude*plant.f_m else 0.0;
  arm_position_um = 1e6*plant.arm_position;
  annotation (
    experiment(StartTime = 0, StopTime = 1.0, Interval = 1e-4, Tolerance = 1e-8),
    Documentation(info = "<html>
<p>
The nominal drive (<a href=\"modelica://HarmonicDrive.Plant\">HarmonicDrive.Plant</a> with its default
parameters) from rest, driven by <code>n_pulses</code> motor torque pulses of amplitude
<code>amplitude</code> f_m and width 1 ms (W* = 0.02236), one every <code>period</code> seconds. Between pulses
the torque is zero and both bodies come to rest; the arm advances by one increment per pulse (see
<code>arm_position_um</code>), as in the impulse controller of the resolution protocol.
</p>
</html>"));
end PulseTrain;
