within MotionTwin.Effects;
function CoulombFriction "Smoothed Coulomb friction force Fc*tanh(v/v_eps) (opposes v)"
  input Real v(unit = "m/s") "Sliding velocity";
  input Real Fc(unit = "N") "Coulomb friction level";
  input Real v_eps(unit = "m/s") "Velocity scale of the tanh regularisation";
  output Real F(unit = "N") "Friction force, positive for positive v";
algorithm
  F := Fc * tanh(v / v_eps);
end CoulombFriction;
