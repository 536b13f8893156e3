within MotionTwin.Effects;
partial model JointBase "Linear-motor joint m*der(v) = u - d*v - F_effect; extending models define F_effect"
  parameter Real m(unit = "kg", min = 1e-9) = 2 "Moving mass";
  parameter Real d(unit = "N.s/m", min = 0) = 10 "Viscous damping coefficient";
  input Real u(unit = "N") "Actuator force";
  output Real q(unit = "m") "Measured position";
  Real x(unit = "m", start = 0, fixed = true) "Position state";
  Real v(unit = "m/s", start = 0, fixed = true) "Velocity state";
  Real F_effect(unit = "N") "Force of the added effect (positive opposes positive motion)";
equation
  der(x) = v;
  m * der(v) = u - d * v - F_effect;
  q = x;
end JointBase;
