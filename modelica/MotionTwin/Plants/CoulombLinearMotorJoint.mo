within MotionTwin.Plants;
model CoulombLinearMotorJoint "Linear motor joint with viscous and smoothed Coulomb friction: m*der(v) = u - d*v - Fc*tanh(v/v_eps)"
  parameter Real m(unit = "kg", min = 1e-9) = 2 "Moving mass";
  parameter Real d(unit = "N.s/m", min = 0) = 10 "Viscous damping coefficient";
  parameter Real Fc(unit = "N", min = 0) = 0 "Coulomb friction force level (opposes the velocity)";
  parameter Real v_eps(unit = "m/s", min = 1e-12) = 1e-3 "Velocity scale of the tanh regularisation (friction reaches 76 % of Fc at v = v_eps)";
  input Real u(unit = "N") "Actuator force";
  output Real q(unit = "m") "Measured position";
  Real x(unit = "m", start = 0, fixed = true) "Position state";
  Real v(unit = "m/s", start = 0, fixed = true) "Velocity state";
equation
  der(x) = v;
  m * der(v) = u - d * v - Fc * tanh(v / v_eps);
  q = x;
  annotation(__motiontwin(export = true));
end CoulombLinearMotorJoint;
