within MotionTwin.Effects;
model VariableInertiaJoint "Joint with position-dependent inertia m(x) = m0*(1 + dm*cos(2*pi*x/period)); Lagrange: m(x)*der(v) + 0.5*m'(x)*v^2 = u - d*v"
  parameter Real m0(unit = "kg", min = 1e-9) = 2 "Mean inertia";
  parameter Real dm(unit = "1", min = -0.99, max = 0.99) = 0.2 "Relative inertia variation";
  parameter Real period(unit = "m", min = 1e-9) = 0.1 "Spatial period of the inertia variation";
  parameter Real d(unit = "N.s/m", min = 0) = 10 "Viscous damping coefficient";
  input Real u(unit = "N") "Actuator force";
  output Real q(unit = "m") "Measured position";
  Real x(unit = "m", start = 0, fixed = true) "Position state";
  Real v(unit = "m/s", start = 0, fixed = true) "Velocity state";
equation
  der(x) = v;
  (m0 * (1 + dm * cos(6.283185307179586 * x / period))) * der(v) = u - d * v + 0.5 * m0 * dm * (6.283185307179586 / period) * sin(6.283185307179586 * x / period) * v ^ 2;
  q = x;
  annotation(__motiontwin(export = true), Documentation(info = "Kinetic energy 0.5*m(x)*v^2, so the power balance u*v - d*v^2 = d/dt(0.5*m(x)*v^2) holds exactly. Effects.PositionDependentMass gives m(x) and m'(x) for use in other models."));
end VariableInertiaJoint;
