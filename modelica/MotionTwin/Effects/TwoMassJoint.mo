within MotionTwin.Effects;
model TwoMassJoint "Joint with an extra structural resonance: motor mass m1 coupled by stiffness k and damping c to load mass m2; the force acts on m1 and the encoder reads m1 (collocated)"
  parameter Real m1(unit = "kg", min = 1e-9) = 1.2 "Motor mass";
  parameter Real m2(unit = "kg", min = 1e-9) = 0.8 "Load mass";
  parameter Real k(unit = "N/m", min = 0) = 5e6 "Coupling stiffness";
  parameter Real c(unit = "N.s/m", min = 0) = 100 "Coupling damping";
  parameter Real d(unit = "N.s/m", min = 0) = 10 "Viscous damping of the motor to ground";
  input Real u(unit = "N") "Actuator force on m1";
  output Real q(unit = "m") "Measured motor position";
  output Real q_load(unit = "m") "Load position";
  Real x1(unit = "m", start = 0, fixed = true) "Motor position";
  Real v1(unit = "m/s", start = 0, fixed = true) "Motor velocity";
  Real x2(unit = "m", start = 0, fixed = true) "Load position";
  Real v2(unit = "m/s", start = 0, fixed = true) "Load velocity";
equation
  der(x1) = v1;
  der(x2) = v2;
  m1 * der(v1) = u - d * v1 - k * (x1 - x2) - c * (v1 - v2);
  m2 * der(v2) = k * (x1 - x2) + c * (v1 - v2);
  q = x1;
  q_load = x2;
  annotation(__motiontwin(export = true), Documentation(info = "Antiresonance at sqrt(k/m2), resonance at sqrt(k*(m1 + m2)/(m1*m2)) (undamped values)."));
end TwoMassJoint;
