model AttributedAxis "parameters with min/max/start/fixed attributes, one without any, states with fixed starts"
  parameter Real m(unit = "kg", min = 0.05, max = 50, start = 1.5, fixed = true) = 1.5 "Moving mass";
  parameter Real d = 11.0;
  parameter Real unused_gain(min = 0, max = 10) = 1 "A parameter the equations do not use";
  input Real u(unit = "N") "Actuator force";
  output Real q(unit = "m") "Measured position";
  Real v(unit = "m/s", start = 0, fixed = true) "Velocity";
equation
  der(q) = v;
  m*der(v) = u - d*v;
end AttributedAxis;
