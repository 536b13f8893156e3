within MotionTwin.Effects;
function LoadDependentFriction "Coulomb friction that grows with the transmitted load, (Fc0 + mu*|F_load|)*tanh(v/v_eps) (gear or screw friction, preload)"
  input Real v(unit = "m/s") "Sliding velocity";
  input Real F_load(unit = "N") "Load carried by the contact (e.g. the drive force)";
  input Real Fc0(unit = "N") "Friction level without load";
  input Real mu "Friction rise per unit load";
  input Real v_eps(unit = "m/s") "Velocity scale of the tanh regularisation";
  output Real F(unit = "N") "Friction force, positive for positive v";
algorithm
  F := (Fc0 + mu * abs(F_load)) * tanh(v / v_eps);
end LoadDependentFriction;
