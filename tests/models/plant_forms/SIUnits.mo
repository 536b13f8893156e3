package SI "Modelica.Units.SI-style type declarations"
  type Mass = Real(final quantity = "Mass", final unit = "kg", min = 0);
  type Position = Real(final quantity = "Length", final unit = "m");
  type Velocity = Real(final quantity = "Velocity", final unit = "m/s");
  type Force = Real(final quantity = "Force", final unit = "N");
  type TranslationalDampingConstant = Real(final quantity = "TranslationalDampingConstant", final unit = "N.s/m");
end SI;

model SITypedAxis "declarations with SI types"
  parameter SI.Mass m = 1.5 "Moving mass";
  parameter SI.TranslationalDampingConstant d = 11.0 "Viscous damping";
  input Real u(unit = "N") "Actuator force (pymoca drops input/output prefixes of derived types)";
  output Real q(unit = "m") "Measured position";
  SI.Position x(start = 0, fixed = true) "Position";
  SI.Velocity v(start = 0, fixed = true) "Velocity";
equation
  der(x) = v;
  m*der(v) = u - d*v;
  q = x;
end SITypedAxis;
