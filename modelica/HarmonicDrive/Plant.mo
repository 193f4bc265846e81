within HarmonicDrive;
model Plant "Harmonic-drive plant: two inertias, gear ratio r = q_l/q_m, flexspline spring, exact Karnopp stick-slip"
  // Interface: names, types, units, start values and ranges are those of fmu_build/variables.py (the FMU's table).
  // One declaration per line: tests/test_modelica.py reads them.

  // Drive parameters
  parameter Real J_m(unit = "kg.m2", min = 1e-12, max = 1e3) = 2e-5 "Motor + wave-generator inertia";
  parameter Real f_m(unit = "N.m", min = 0.0, max = 1e6) = 0.01 "Motor-side Coulomb (= static) friction level";
  parameter Real K_s(unit = "N.m/rad", min = 1e-3, max = 1e15) = 1.0e4 "Torsional stiffness of the flexspline (load side)";
  parameter Real J_l(unit = "kg.m2", min = 1e-12, max = 1e6) = 0.05 "Flexspline + arm inertia";
  parameter Real f_l(unit = "N.m", min = 0.0, max = 1e6) = 1e-3 "Load-side Coulomb (= static) friction level";
  parameter Real r(unit = "1", min = 1e-6, max = 1.0) = 0.01 "Gear ratio q_l/q_m at rest (r < 1: 0.01 is a 100:1 drive)";
  parameter Integer encoder_counts_per_rev(min = 1, max = 2147483647) = 12566 "Motor encoder counts per motor revolution";
  parameter Real arm_length(unit = "m", min = 1e-6, max = 1e3) = 0.3 "Arm length: arm_position = arm_length * q_l";

  // Optional effects (the discrepancy library); every default switches its effect off
  parameter Real b_m(unit = "N.m.s/rad", min = 0.0, max = 1e6) = 0.0 "Motor viscous friction coefficient";
  parameter Real b_l(unit = "N.m.s/rad", min = 0.0, max = 1e6) = 0.0 "Load viscous friction coefficient";
  parameter Real stribeck_ratio(unit = "1", min = 0.0, max = 10.0) = 0.0 "Static level / Coulomb level - 1 (both bodies)";
  parameter Real stribeck_velocity(unit = "rad/s", min = 1e-12, max = 1e6) = 1e-3 "Stribeck velocity vs on the load side; the motor uses stribeck_velocity / r";
  parameter Real friction_asymmetry(unit = "1", min = -0.99, max = 0.99) = 0.0 "Friction levels f (1 + a) for positive, f (1 - a) for negative motion";
  parameter Real hardening(unit = "1/rad2", min = 0.0, max = 1e20) = 0.0 "K3/K_s: spring torque K_s (d + hardening d^3)";
  parameter Real hysteresis_torque(unit = "N.m", min = 0.0, max = 1e6) = 0.0 "Saturation torque H of the Dahl hysteresis element (0 = off)";
  parameter Real hysteresis_stiffness(unit = "N.m/rad", min = 0.001, max = 1e15) = 1.0e4 "Initial stiffness sigma of the Dahl element";
  parameter Real kinematic_error(unit = "rad", min = 0.0, max = 1.0) = 0.0 "Amplitude A of the transmission error (load side)";
  parameter Real kinematic_error_phase(unit = "rad", min = -10.0, max = 10.0) = 0.0 "Phase phi of the transmission error";
  parameter Real viscous_asymmetry(unit = "1", min = -0.99, max = 0.99) = 0.0 "Viscous coefficients b (1 + a_v) for positive, b (1 - a_v) for negative motion";
  parameter Real kinematic_error_4(unit = "rad", min = 0.0, max = 1.0) = 0.0 "Amplitude A4 of the error's second harmonic, four times per wave-generator turn";
  parameter Real kinematic_error_4_phase(unit = "rad", min = -10.0, max = 10.0) = 0.0 "Phase phi4 of the second harmonic";
  parameter Real stribeck_shape(unit = "1", min = 1.0, max = 4.0) = 2.0 "Exponent delta of the Stribeck decay exp(-|v/vs|^delta): 2 Gaussian, 1 exponential";
  parameter Real hysteresis_exponent(unit = "1", min = 1.0, max = 4.0) = 1.0 "Exponent n of the Dahl element: z' = sigma dd |1 - sgn(dd) z/H|^n sgn(1 - sgn(dd) z/H)";
  parameter Real hardening_exponent(unit = "1", min = 1.0, max = 4.0) = 2.0 "Exponent p of the hardening: spring torque K_s (d + hardening d |d|^p hardening_deflection^(2 - p)); 2 the cubic";
  parameter Real hardening_deflection(unit = "rad", min = 1e-12, max = 1e3) = 1.0 "Deflection at which a hardening of exponent p != 2 stiffens as the cubic does";

  // Initial state
  parameter Real q_m_start(unit = "rad", min = -1e6, max = 1e6) = 0.0 "Initial motor angle";
  parameter Real q_l_start(unit = "rad", min = -1e6, max = 1e6) = 0.0 "Initial load angle";
  parameter Real v_m_start(unit = "rad/s", min = -1e6, max = 1e6) = 0.0 "Initial motor velocity";
  parameter Real v_l_start(unit = "rad/s", min = -1e6, max = 1e6) = 0.0 "Initial load velocity";

  // Input
  input Real motor_torque(unit = "N.m", min = -1e6, max = 1e6, start = 0.0) "Motor torque T_m, held constant over each communication step";

  // Outputs
  output Real q_m(unit = "rad") "Motor angle";
  output Real q_l(unit = "rad") "Load (arm) angle";
  output Real v_m(unit = "rad/s") "Motor velocity";
  output Real v_l(unit = "rad/s") "Load velocity";
  output Real spring_torque(unit = "N.m") "Total transmitted torque K_s (d + hardening d^3) + hysteresis_state on the load";
  output Boolean motor_stuck "Motor is stuck (zero velocity, net torque within its static level)";
  output Boolean load_stuck "Load is stuck (zero velocity, net torque within its static level)";
  output Integer encoder_count "Motor encoder count floor(q_m / (2 pi / counts_per_rev)), saturated to int32";
  output Real arm_position(unit = "m") "Arm tip position arm_length * q_l";
  output Real input_work(unit = "J") "Work done by the motor torque since the start";
  output Real friction_work(unit = "J") "Energy dissipated by friction since the start";
  output Real deflection(unit = "rad") "Spring deflection d = r q_m + e(q_m) - q_l, e the kinematic error";
  output Real hysteresis_state(unit = "N.m") "Torque z of the Dahl hysteresis element";
  output Real motor_friction_torque(unit = "N.m") "Friction torque F_m on the motor (the holding reaction while stuck)";
  output Real load_friction_torque(unit = "N.m") "Friction torque F_l on the load (the holding reaction while stuck)";

protected
  constant Real pi = 3.14159265358979323846;
  Real g(unit = "1") "Gear factor d(deflection)/d(q_m) = r + 2 A cos(2 q_m + phi)";
  Real dd(unit = "rad/s") "Twist rate g v_m - v_l";
  Real tau_m(unit = "N.m") "Net non-friction torque on the motor";
  Real tau_l(unit = "N.m") "Net non-friction torque on the load";
  Real up_m(unit = "N.m") "Motor static level, positive motion";
  Real down_m(unit = "N.m") "Motor static level, negative motion";
  Real up_l(unit = "N.m") "Load static level, positive motion";
  Real down_l(unit = "N.m") "Load static level, negative motion";
  discrete Integer mode_m "Motor friction state: 0 stuck, +1 slipping forwards, -1 slipping backwards";
  discrete Integer mode_l "Load friction state: 0 stuck, +1 slipping forwards, -1 slipping backwards";

initial equation
  q_m = q_m_start;
  q_l = q_l_start;
  v_m = v_m_start;
  v_l = v_l_start;
  input_work = 0;
  friction_work = 0;
  hysteresis_state = 0;
  // Karnopp at t = 0: a moving body slips with its velocity; a body at rest sticks unless its net torque exceeds
  // its static level, then it breaks away in the direction of that torque.
  mode_m = if v_m_start > 0 then 1 elseif v_m_start < 0 then -1 elseif tau_m > up_m then 1 elseif tau_m < -down_m then -1 else 0;
  mode_l = if v_l_start > 0 then 1 elseif v_l_start < 0 then -1 elseif tau_l > up_l then 1 elseif tau_l < -down_l then -1 else 0;

equation
  up_m = f_m*(1 + friction_asymmetry)*(1 + stribeck_ratio);
  down_m = f_m*(1 - friction_asymmetry)*(1 + stribeck_ratio);
  up_l = f_l*(1 + friction_asymmetry)*(1 + stribeck_ratio);
  down_l = f_l*(1 - friction_asymmetry)*(1 + stribeck_ratio);
  deflection = r*q_m + kinematic_error*sin(2*q_m + kinematic_error_phase) + kinematic_error_4*sin(4*q_m + kinematic_error_4_phase) - q_l;
  g = r + 2*kinematic_error*cos(2*q_m + kinematic_error_phase) + 4*kinematic_error_4*cos(4*q_m + kinematic_error_4_phase);
  spring_torque = K_s*(deflection + hardening*deflection*abs(deflection)^hardening_exponent*hardening_deflection^(2 - hardening_exponent)) + hysteresis_state;
  tau_m = motor_torque - g*spring_torque;
  tau_l = spring_torque;

  // Dahl hysteresis: z' = sigma dd (1 - sgn(dd) z/H) = sigma (dd - |dd| z/H); off (z = 0) when H = 0.
  dd = g*v_m - v_l;
  der(hysteresis_state) = if hysteresis_torque > 0 then hysteresis_stiffness*dd*abs(1 - sign(dd)*hysteresis_state/hysteresis_torque)^hysteresis_exponent*sign(1 - sign(dd)*hysteresis_state/hysteresis_torque) else 0;

  // Friction: a stuck body's friction balances its net torque exactly (so its velocity stays exactly zero);
  // a slipping body's friction is its (asymmetric) Coulomb level with the Stribeck rise against the slip
  // direction, plus viscous friction (its coefficient b (1 + viscous_asymmetry*mode) depends on the direction too).
  motor_friction_torque = if mode_m == 0 then tau_m else mode_m*f_m*(1 + friction_asymmetry*mode_m)*(1 + stribeck_ratio*exp(-abs(v_m*r/stribeck_velocity)^stribeck_shape)) + b_m*(1 + viscous_asymmetry*mode_m)*v_m;
  load_friction_torque = if mode_l == 0 then tau_l else mode_l*f_l*(1 + friction_asymmetry*mode_l)*(1 + stribeck_ratio*exp(-abs(v_l/stribeck_velocity)^stribeck_shape)) + b_l*(1 + viscous_asymmetry*mode_l)*v_l;

  der(q_m) = v_m;
  der(q_l) = v_l;
  J_m*der(v_m) = tau_m - motor_friction_torque;
  J_l*der(v_l) = tau_l - load_friction_torque;

  // The state machine (Karnopp). Each body re-decides whenever
  //   - it is stuck and |net non-friction torque| exceeds its static level (breakaway), or
  //   - it is slipping and its velocity reaches zero (the crossing against the slip direction).
  // The decision is the same in both cases: stick while -down <= tau <= up (the static band, asymmetric with
  // friction_asymmetry), else slip in the direction of tau.
  // The velocity is set to exactly zero at every decision (it is zero, up to the event tolerance, there).
  when (pre(mode_m) == 0 and (tau_m > up_m or tau_m < -down_m)) or (pre(mode_m) == 1 and v_m < 0) or (pre(mode_m) == -1 and v_m > 0) then
    mode_m = if tau_m > up_m then 1 elseif tau_m < -down_m then -1 else 0;
    reinit(v_m, 0);
  end when;
  when (pre(mode_l) == 0 and (tau_l > up_l or tau_l < -down_l)) or (pre(mode_l) == 1 and v_l < 0) or (pre(mode_l) == -1 and v_l > 0) then
    mode_l = if tau_l > up_l then 1 elseif tau_l < -down_l then -1 else 0;
    reinit(v_l, 0);
  end when;
  motor_stuck = mode_m == 0;
  load_stuck = mode_l == 0;

  // Outputs
  encoder_count = integer(max(min(floor(q_m*encoder_counts_per_rev/(2*pi)), 2147483647.0), -2147483648.0));
  arm_position = arm_length*q_l;
  der(input_work) = motor_torque*v_m;
  der(friction_work) = motor_friction_torque*v_m + load_friction_torque*v_l;

  annotation (Documentation(info = "<html>
<p>
The harmonic-drive stick-slip plant: the Modelica twin of the C plant in <code>fmu_build/c</code> exported as
<code>HarmonicDrive.fmu</code> (FMI 2.0 / 3.0). It has the same parameter, input and output names, types,
units, start values and ranges (<code>fmu_build/variables.py</code>); <code>tests/test_modelica.py</code> checks
them against the FMU's modelDescription.xml.
</p>
<p>
Convention: r = q_l/q_m at rest (r &lt; 1), deflection d = r q_m - q_l,
</p>
<pre>
  J_m q_m'' = motor_torque - F_m - r K_s d
  J_l q_l'' = K_s d - F_l
</pre>
<p>
spring_torque = K_s d (base model), arm_position = arm_length q_l, encoder_count = floor(q_m/(2 pi/encoder_counts_per_rev))
saturated to the Integer (int32) range, input_work = integral of motor_torque v_m dt, friction_work = integral of
(F_m v_m + F_l v_l) dt (the energy friction dissipates, never negative).
</p>
<h4>Optional effects (all off by default)</h4>
<p>
The same parameters as the FMU (value references 100+): viscous friction <code>b_m</code>, <code>b_l</code>,
direction-dependent as b (1 &plusmn; <code>viscous_asymmetry</code>);
Stribeck friction (<code>stribeck_ratio</code> s, <code>stribeck_velocity</code> vs, load side, vs/r on the
motor; the decay exp(-|v/vs|^delta), <code>stribeck_shape</code> delta: 2 Gaussian, 1 exponential); asymmetric levels f (1 &plusmn; <code>friction_asymmetry</code>); a hardening spring
K_s (d + <code>hardening</code> d^3) (at <code>hardening_exponent</code> p other than 2, d |d|^p d_h^(2 - p), d_h =
<code>hardening_deflection</code>); a Dahl hysteresis element z' = sigma dd |1 - sgn(dd) z/H|^n sgn(1 - sgn(dd) z/H) in parallel
with the spring (<code>hysteresis_torque</code> H, <code>hysteresis_stiffness</code> sigma, <code>hysteresis_exponent</code> n,
1 by default); a kinematic error
d = r q_m + A sin(2 q_m + phi) + A4 sin(4 q_m + phi4) - q_l (<code>kinematic_error</code>, <code>kinematic_error_phase</code>,
<code>kinematic_error_4</code>, <code>kinematic_error_4_phase</code>).
Then J_m q_m'' = T - g tau_s - F_m, J_l q_l'' = tau_s - F_l with g = r + 2 A cos(2 q_m + phi),
tau_s = spring_torque; a slipping body feels F = dir f (1 + a dir)(1 + s exp(-(v/vs)^2)) + b (1 + a_v dir) v, a stuck body
stays stuck while -f (1 - a)(1 + s) &lt;= N &lt;= f (1 + a)(1 + s).
</p>
<h4>Stick-slip: an explicit state machine</h4>
<p>
Friction is modelled by an explicit Karnopp state machine per body (a discrete Integer mode: 0 stuck, +1 / -1
slipping forwards / backwards) driven by <code>when</code> clauses with <code>reinit</code>, not by the
Modelica Standard Library's <code>BearingFriction</code> / <code>PartialFriction</code>: the library needs no
other library, the friction law is exactly the one of the C plant (static level = Coulomb level, no Stribeck
curve, no viscous term), and the decision rule reads like the C code:
</p>
<ul>
<li>stuck: the friction torque equals the net non-friction torque tau (tau_m = motor_torque - r K_s d on the
motor, tau_l = K_s d on the load), so the acceleration and velocity are exactly zero;</li>
<li>slipping: the friction torque is f times the slip direction;</li>
<li>when a stuck body's |tau| exceeds its level f, or a slipping body's velocity reaches zero, the body decides:
stick if |tau| &lt;= f, else slip in the direction of tau (breakaway or reversal); its velocity is reset to 0.</li>
</ul>
<p>
Nothing creeps or chatters at rest. The C plant solves every segment in closed form and locates the events as
roots of known functions; a Modelica tool integrates numerically, so its results agree with the FMU to the
integration and event tolerances.
</p>
</html>"));
end Plant;
