model RigidJoint "rigid moving mass with viscous friction: the output is the position state itself"
  parameter Real m(unit="kg") = 1.5 "moving mass";
  parameter Real d(unit="N.s/m") = 11.0 "viscous friction coefficient";
  input Real u(unit="N") "actuator force";
  output Real q(unit="m") "measured position";
  Real v(unit="m/s") "velocity";
equation
  der(q) = v;
  m*der(v) = u - d*v;
end RigidJoint;
