within HarmonicDrive;
package Examples "Example experiments with the harmonic-drive plant"
  annotation (Documentation(info = "<html>
<p>Small experiments with <a href=\"modelica://HarmonicDrive.Plant\">HarmonicDrive.Plant</a>.</p>
</html>"));
end Examples;
