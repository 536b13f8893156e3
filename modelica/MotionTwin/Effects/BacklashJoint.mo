within MotionTwin.Effects;
model BacklashJoint "Joint with backlash: motor mass m1 drives load mass m2 through a compliant transmission (stiffness k, damping c) with a gap of 2*b; the encoder reads the motor"
  parameter Real m1(unit = "kg", min = 1e-9) = 1.2 "Motor mass";
  parameter Real m2(unit = "kg", min = 1e-9) = 0.8 "Load mass";
  parameter Real k(unit = "N/m", min = 0) = 2e6 "Transmission stiffness in contact";
  parameter Real c(unit = "N.s/m", min = 0) = 200 "Transmission damping in contact";
  parameter Real b(unit = "m", min = 0) = 5e-6 "Half-width of the gap (total backlash 2*b)";
  parameter Real eps(unit = "m", min = 1e-15) = 1e-8 "Rounding of the gap corners";
  parameter Real d(unit = "N.s/m", min = 0) = 10 "Viscous damping of the motor to ground";
  input Real u(unit = "N") "Actuator force on the motor";
  output Real q(unit = "m") "Measured motor position";
  output Real q_load(unit = "m") "Load position";
  output Real F_transmission(unit = "N") "Force the transmission passes to the load";
  Real x1(unit = "m", start = 0, fixed = true) "Motor position";
  Real v1(unit = "m/s", start = 0, fixed = true) "Motor velocity";
  Real x2(unit = "m", start = 0, fixed = true) "Load position";
  Real v2(unit = "m/s", start = 0, fixed = true) "Load velocity";
equation
  der(x1) = v1;
  der(x2) = v2;
  F_transmission = k * MotionTwin.Effects.DeadZone(x1 - x2, b, eps) + c * MotionTwin.Effects.DeadZoneSlope(x1 - x2, b, eps) * (v1 - v2);
  m1 * der(v1) = u - d * v1 - F_transmission;
  m2 * der(v2) = F_transmission;
  q = x1;
  q_load = x2;
  annotation(Documentation(info = "Inside the gap (|x1 - x2| < b) the motor moves alone (mass m1); in contact the pair is the two-mass resonator of TwoMassJoint. Damping acts only in contact."));
end BacklashJoint;
