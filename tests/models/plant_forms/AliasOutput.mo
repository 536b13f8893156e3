model AliasAxis "the output is an algebraic alias of the position state"
  parameter Real m(unit = "kg", min = 1e-6) = 1.5 "Moving mass";
  parameter Real d(unit = "N.s/m", min = 0) = 11.0 "Viscous damping";
  input Real u(unit = "N") "Actuator force";
  output Real q(unit = "m") "Measured position";
  Real x(unit = "m", start = 0, fixed = true) "Position";
  Real v(unit = "m/s", start = 0, fixed = true) "Velocity";
equation
  der(x) = v;
  m*der(v) = u - d*v;
  q = x;
end AliasAxis;
