within MotionTwin.Plants;
function CheungForwardKinematics "4-DOF manipulator forward kinematics, Cheung and Hung eqs. (2)-(3): actuator positions to end-effector pose"
  input Real d1(unit = "m") "Actuator d1 position (X axis, inner)";
  input Real d3(unit = "m") "Actuator d3 position (X axis, outer)";
  input Real d5(unit = "m") "Actuator d5 position (Y axis, outer)";
  input Real d7(unit = "m") "Actuator d7 position (Y axis, inner)";
  input Real l(unit = "m") "Link length l = l2 = l4 = l6 = l8";
  input Real k(unit = "m") "Link length k = k10 = k12";
  input Real dx(unit = "m") "Offset dx";
  input Real dy(unit = "m") "Offset dy";
  input Real dz(unit = "m") "Offset dz";
  output Real x(unit = "m") "End-effector x";
  output Real y(unit = "m") "End-effector y";
  output Real z(unit = "m") "End-effector z";
  output Real theta(unit = "rad") "End-effector rotation about Z";
protected
  Real x1 "P x";
  Real y1 "P y";
  Real x2 "Q x";
  Real y2 "Q y";
algorithm
  x1 := (d1 + d3) / 2;
  y1 := sqrt(l ^ 2 - (d3 - d1) ^ 2 / 4) + dy;
  x2 := sqrt(l ^ 2 - (d5 - d7) ^ 2 / 4) + dx;
  y2 := (d5 + d7) / 2;
  x := (x1 + x2) / 2;
  y := (y1 + y2) / 2;
  z := sqrt(k ^ 2 - ((x2 - x1) ^ 2 + (y2 - y1) ^ 2) / 4) + dz;
  theta := atan2(y1 - y2, x1 - x2);
end CheungForwardKinematics;
