model InstrumentedAxis "an unused feedforward input and extra outputs besides the measured position"
  parameter Real m(unit = "kg") = 1.5 "Moving mass";
  parameter Real d(unit = "N.s/m") = 11.0 "Viscous damping";
  input Real u(unit = "N") "Actuator force";
  input Real u_ff(unit = "N") "Spare input, not connected in the experiment";
  output Real q(unit = "m") "Measured position";
  output Real speed(unit = "m/s") "Velocity output";
  output Real power(unit = "W") "Mechanical power";
  Real x(unit = "m") "Position";
  Real v(unit = "m/s") "Velocity";
equation
  der(x) = v;
  m*der(v) = u - d*v;
  q = x;
  speed = v;
  power = u*v;
end InstrumentedAxis;
