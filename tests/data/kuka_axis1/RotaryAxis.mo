model RotaryAxis "One rotary robot axis, link side: J*der(w) = tau - d*w - Tc*tanh(w/w_eps) - T0"
  parameter Real J(unit = "kg.m2", min = 1e-6) = 1500 "Inertia about the axis, link side (rotor inertia reflected through the gear included)";
  parameter Real d(unit = "N.m.s/rad", min = 0) = 1900 "Viscous friction coefficient, link side";
  parameter Real Tc(unit = "N.m", min = 0) = 0 "Coulomb friction level (opposes the velocity)";
  parameter Real T0(unit = "N.m") = 0 "Constant torque opposing positive motion (asymmetry / offset)";
  parameter Real w_eps(unit = "rad/s", min = 1e-12) = 0.01 "Velocity scale of the tanh regularisation";
  input Real u(unit = "N.m") "Joint torque, link side (motor torque x gear ratio)";
  output Real q(unit = "rad") "Measured joint position";
  Real x(unit = "rad", start = 0, fixed = true) "Joint position";
  Real w(unit = "rad/s", start = 0, fixed = true) "Joint velocity";
equation
  der(x) = w;
  J * der(w) = u - d * w - Tc * tanh(w / w_eps) - T0;
  q = x;
end RotaryAxis;
