model OffsetSensorAxis "the encoder reads the position plus a mounting offset"
  parameter Real m(unit = "kg") = 1.5 "Moving mass";
  parameter Real d(unit = "N.s/m") = 11.0 "Viscous damping";
  parameter Real offset(unit = "m") = 0.0025 "Encoder mounting offset";
  input Real u(unit = "N") "Actuator force";
  output Real q(unit = "m") "Measured position";
  Real s(unit = "m") "Carriage position";
  Real sd(unit = "m/s") "Carriage velocity";
equation
  der(s) = sd;
  m*der(sd) = u - d*sd;
  q = s + offset;
end OffsetSensorAxis;
