within MotionTwin.Plants;
model LinearMotorJoint "Direct-drive linear motor joint: moving mass with viscous damping, m*der(v) = u - d*v"
  parameter Real m(unit = "kg", min = 1e-9) = 2 "Moving mass";
  parameter Real d(unit = "N.s/m", min = 0) = 10 "Viscous damping coefficient";
  input Real u(unit = "N") "Actuator force";
  output Real q(unit = "m") "Measured position";
  Real x(unit = "m", start = 0, fixed = true) "Position state";
  Real v(unit = "m/s", start = 0, fixed = true) "Velocity state";
equation
  der(x) = v;
  m * der(v) = u - d * v;
  q = x;
  annotation(__motiontwin(export = true));
end LinearMotorJoint;
