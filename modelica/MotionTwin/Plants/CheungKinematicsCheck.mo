within MotionTwin.Plants;
model CheungKinematicsCheck "Evaluates the 4-DOF forward kinematics of input actuator positions and the inverse kinematics of an input pose (exposes the kinematic functions through the front end for testing; input start values are the paper's start pose)"
  parameter Real l(unit = "m", min = 1e-9) = 0.070 "Link length l (Table 1)";
  parameter Real k(unit = "m", min = 1e-9) = 0.1166 "Link length k (Table 1)";
  parameter Real dx(unit = "m") = 0.010 "Offset dx (Table 1)";
  parameter Real dy(unit = "m") = 0.010 "Offset dy (Table 1)";
  parameter Real dz(unit = "m") = 0.010 "Offset dz (Table 1)";
  input Real d1(unit = "m", start = 0.0794232635) "Actuator d1";
  input Real d3(unit = "m", start = 0.1399244463) "Actuator d3";
  input Real d5(unit = "m", start = 0.1399243734) "Actuator d5";
  input Real d7(unit = "m", start = 0.0794234707) "Actuator d7";
  input Real xp(unit = "m", start = 0.0914) "Pose x for the inverse kinematics";
  input Real yp(unit = "m", start = 0.0914) "Pose y for the inverse kinematics";
  input Real zp(unit = "m", start = 0.1237) "Pose z for the inverse kinematics";
  input Real thetap(unit = "rad", start = -0.7854) "Pose theta for the inverse kinematics";
  output Real x(unit = "m") "End-effector x from the forward kinematics";
  output Real y(unit = "m") "End-effector y from the forward kinematics";
  output Real z(unit = "m") "End-effector z from the forward kinematics";
  output Real theta(unit = "rad") "End-effector rotation from the forward kinematics";
  output Real e1(unit = "m") "d1 from the inverse kinematics";
  output Real e3(unit = "m") "d3 from the inverse kinematics";
  output Real e5(unit = "m") "d5 from the inverse kinematics";
  output Real e7(unit = "m") "d7 from the inverse kinematics";
equation
  (x, y, z, theta) = MotionTwin.Plants.CheungForwardKinematics(d1, d3, d5, d7, l, k, dx, dy, dz);
  (e1, e3, e5, e7) = MotionTwin.Plants.CheungInverseKinematics(xp, yp, zp, thetap, l, k, dx, dy, dz);
  annotation(__motiontwin(export = true));
end CheungKinematicsCheck;
