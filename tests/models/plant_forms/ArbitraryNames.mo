model Carriage "every name differs from the library's: input F, output y, states pos_m and vel_mps"
  parameter Real mass(unit = "kg") = 1.5 "Carriage mass";
  parameter Real damping(unit = "N.s/m") = 11.0 "Viscous damping";
  input Real F(unit = "N") "Motor force";
  output Real y(unit = "m") "Encoder reading";
  Real pos_m(unit = "m", start = 0) "Carriage position";
  Real vel_mps(unit = "m/s", start = 0) "Carriage velocity";
equation
  der(pos_m) = vel_mps;
  mass*der(vel_mps) = F - damping*vel_mps;
  y = pos_m;
end Carriage;
