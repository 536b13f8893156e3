within MotionTwin.Plants;
function CheungInverseKinematics "4-DOF manipulator inverse kinematics, Cheung and Hung eqs. (4)-(5) with the errata (d7 line of eq. (5); y lines of eq. (4): y1 = y + r*sin(theta), y2 = y - r*sin(theta))"
  input Real x(unit = "m") "End-effector x";
  input Real y(unit = "m") "End-effector y";
  input Real z(unit = "m") "End-effector z";
  input Real theta(unit = "rad") "End-effector rotation about Z";
  input Real l(unit = "m") "Link length l";
  input Real k(unit = "m") "Link length k";
  input Real dx(unit = "m") "Offset dx";
  input Real dy(unit = "m") "Offset dy";
  input Real dz(unit = "m") "Offset dz";
  output Real d1(unit = "m") "Actuator d1";
  output Real d3(unit = "m") "Actuator d3";
  output Real d5(unit = "m") "Actuator d5";
  output Real d7(unit = "m") "Actuator d7";
protected
  Real r "Half distance P-Q in the XY plane";
  Real x1 "P x";
  Real y1 "P y";
  Real x2 "Q x";
  Real y2 "Q y";
  Real h1 "Half spread of d1, d3";
  Real h2 "Half spread of d5, d7";
algorithm
  r := sqrt(k ^ 2 - (z - dz) ^ 2);
  x1 := x + r * cos(theta);
  x2 := x - r * cos(theta);
  y1 := y + r * sin(theta);
  y2 := y - r * sin(theta);
  h1 := sqrt(l ^ 2 - (y1 - dy) ^ 2);
  h2 := sqrt(l ^ 2 - (x2 - dx) ^ 2);
  d1 := x1 - h1;
  d3 := x1 + h1;
  d5 := y2 + h2;
  d7 := y2 - h2;
end CheungInverseKinematics;
