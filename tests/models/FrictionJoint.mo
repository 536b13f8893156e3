model FrictionJoint "Linear-motor joint with smoothed Coulomb friction (stiff near v = 0)"
  parameter Real m(unit = "kg", min = 1e-9) = 2 "moving mass";
  parameter Real d(unit = "N.s/m", min = 0) = 10 "viscous damping";
  parameter Real Fc(unit = "N", min = 0) = 5 "Coulomb friction force";
  parameter Real v_eps(unit = "m/s", min = 1e-12) = 1e-4 "velocity scale of the tanh regularisation";
  input Real u(unit = "N") "actuator force";
  output Real q(unit = "m", start = 0) "position";
  Real v(unit = "m/s", start = 0) "velocity";
  output Real a(unit = "m/s2") "acceleration";
equation
  der(q) = v;
  m * der(v) = u - d * v - Fc * tanh(v / v_eps);
  a = der(v);
end FrictionJoint;
