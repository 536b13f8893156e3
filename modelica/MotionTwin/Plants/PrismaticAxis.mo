within MotionTwin.Plants;
model PrismaticAxis "Prismatic axis with viscous and smoothed Coulomb friction and a constant force: m*der(v) = u - d*v - Fc*tanh(v/v_eps) - F0"
  parameter Real m(unit = "kg", min = 1e-9) = 2 "Moving mass";
  parameter Real d(unit = "N.s/m", min = 0) = 10 "Viscous damping coefficient";
  parameter Real Fc(unit = "N", min = 0) = 0 "Coulomb friction force level (opposes the velocity)";
  parameter Real F0(unit = "N") = 0 "Constant force opposing positive motion (weight on an inclined axis, preload, amplifier offset); Coulomb Fc with F0 equals asymmetric Coulomb levels Fc + F0 (v > 0) and Fc - F0 (v < 0)";
  parameter Real v_eps(unit = "m/s", min = 1e-12) = 1e-3 "Velocity scale of the tanh regularisation (friction reaches 76 % of Fc at v = v_eps)";
  input Real u(unit = "N") "Actuator force";
  output Real q(unit = "m") "Measured position";
  Real x(unit = "m", start = 0, fixed = true) "Position state";
  Real v(unit = "m/s", start = 0, fixed = true) "Velocity state";
equation
  der(x) = v;
  m * der(v) = u - d * v - Fc * tanh(v / v_eps) - F0;
  q = x;
end PrismaticAxis;
