model ServoPendulum "XL330 servo (motor + 288:1 gearbox) driving a pendulum that hangs at q = 0: J der(w) = u - d w - k sin(q)"
  parameter Real J(unit = "kg.m2", min = 1e-9) = 0.0065 "Inertia: rotor through the gearbox + pendulum";
  parameter Real d(unit = "N.m.s/rad", min = 0) = 0.03 "Viscous: back-EMF + gearbox";
  parameter Real k(unit = "N.m") = 0.4807 "Gravity torque m g l";
  input Real u(unit = "N.m") "Motor torque";
  output Real q(unit = "rad") "Position";
  Real x(unit = "rad", start = 0, fixed = true);
  Real w(unit = "rad/s", start = 0, fixed = true);
equation
  der(x) = w;
  J * der(w) = u - d * w - k * sin(x);
  q = x;
end ServoPendulum;
