model BallScrewAxis "motor angle and speed as states; the measured table position is the angle times the screw lead (2 mm/rad)"
  parameter Real J(unit = "kg.m2") = 6.0e-6 "Inertia seen by the motor (table mass times lead squared)";
  parameter Real b(unit = "N.m.s/rad") = 4.4e-5 "Viscous damping seen by the motor";
  input Real u(unit = "N") "Axial actuator force";
  output Real q(unit = "m") "Measured table position";
  Real phi(unit = "rad") "Motor angle";
  Real w(unit = "rad/s") "Motor speed";
equation
  der(phi) = w;
  J*der(w) = 0.002*u - b*w;
  q = 0.002*phi;
end BallScrewAxis;
