package HarmonicDrive "Harmonic-drive stick-slip plant (Modelica twin of the HarmonicDrive FMU)"
  annotation (
    version = "0.1.0",
    Documentation(info = "<html>
<p>
<b>HarmonicDrive</b> is the Modelica twin of the C plant that <code>fmu_build/</code> of the hdrive project
compiles into <code>HarmonicDrive.fmu</code> (FMI 2.0 and FMI 3.0 co-simulation). The main model is
<a href=\"modelica://HarmonicDrive.Plant\">HarmonicDrive.Plant</a>; it has exactly the parameter, input and output
names, types, units, start values and ranges of the FMU, all taken from the single variable table
<code>fmu_build/variables.py</code>. <code>tests/test_modelica.py</code> holds the two to the same interface.
</p>
<h4>The plant</h4>
<p>
Two inertias: the motor with the wave generator (<code>J_m</code>, angle <code>q_m</code>) and the flexspline with
the arm (<code>J_l</code>, angle <code>q_l</code>), a gear ratio <code>r</code> and a torsional spring
<code>K_s</code> on the load side. <b>Convention: r = q_l/q_m at rest, so r &lt; 1</b> (r = 0.01 is a 100:1
drive). The spring deflection is d = r q_m - q_l (load-side radians) and
</p>
<pre>
  J_m q_m'' = T_m - F_m - r K_s d
  J_l q_l'' = K_s d - F_l
</pre>
<p>
with <code>T_m = motor_torque</code>. Friction is Coulomb friction whose static level equals its Coulomb level
(<code>f_m</code> on the motor, <code>f_l</code> on the load), with exact Karnopp stick-slip: a body at zero
velocity stays stuck while the magnitude of the net non-friction torque on it is at most its level, otherwise it
breaks away in the direction of that torque; a slipping body feels -sgn(v) times its level. Viscous terms
(back-EMF damping) are neglected in this base model.
</p>
<h4>Non-dimensional parameters</h4>
<p>
T_c = sqrt(J_m/f_m) (time scale), t* = t/T_c, tau* = T_m/f_m, K* = K_s/f_m [1/rad], J_l* = J_l/J_m,
f_l* = f_l/f_m, r* = r. Angles stay in radians:
</p>
<pre>
  q_m'' = -sgn(q_m') - r* K* (r* q_m - q_l) + tau*
  q_l'' = -(f_l*/J_l*) sgn(q_l') + (K*/J_l*) (r* q_m - q_l)
</pre>
<h4>The nominal drive (the start values)</h4>
<p>
J_m = 2e-5 kg.m2, f_m = 0.01 N.m, K_s = 1e4 N.m/rad, J_l = 0.05 kg.m2, f_l = 1e-3 N.m (f_l* = 0.1), r = 0.01,
arm length 0.3 m, motor encoder 12566 counts/rev (one count = 1.50 um at the arm). Hence K* = 1e6,
J_l* = 2500, f_l* = 0.1, T_c = 44.72 ms; a 1 ms torque pulse is W* = 0.02236.
</p>
<h4>Contents</h4>
<ul>
<li><a href=\"modelica://HarmonicDrive.Plant\">Plant</a>: the plant (the twin of the FMU).</li>
<li><a href=\"modelica://HarmonicDrive.Examples.PulseTrain\">Examples.PulseTrain</a>: the plant driven by
a train of 1 ms torque pulses (the impulse controller of the resolution protocol, open loop).</li>
</ul>
</html>"));
end HarmonicDrive;
