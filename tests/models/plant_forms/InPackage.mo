package Machines "a plant class inside a package"
  model LinearStage "rigid stage"
    parameter Real m(unit = "kg") = 1.5 "Moving mass";
    parameter Real d(unit = "N.s/m") = 11.0 "Viscous damping";
    input Real u(unit = "N") "Actuator force";
    output Real q(unit = "m") "Measured position";
    Real v(unit = "m/s") "Velocity";
  equation
    der(q) = v;
    m*der(v) = u - d*v;
  end LinearStage;
end Machines;
