partial model MassBase "moving mass: parameters, position and velocity"
  parameter Real m(unit = "kg") = 1.5 "Moving mass";
  Real x(unit = "m") "Position";
  Real v(unit = "m/s") "Velocity";
  input Real u(unit = "N") "Actuator force";
  output Real q(unit = "m") "Measured position";
equation
  der(x) = v;
  q = x;
end MassBase;

model DampedMass "extends the base with viscous damping"
  extends MassBase;
  parameter Real d(unit = "N.s/m") = 11.0 "Viscous damping";
equation
  m*der(v) = u - d*v;
end DampedMass;
