within MotionTwin.Effects;
function StribeckFriction "Smoothed Stribeck friction (Fc + (Fs - Fc)*exp(-(v/vs)^2))*tanh(v/v_eps) (opposes v, viscous part not included)"
  input Real v(unit = "m/s") "Sliding velocity";
  input Real Fc(unit = "N") "Coulomb (sliding) friction level";
  input Real Fs(unit = "N") "Static (breakaway) friction level, Fs >= Fc";
  input Real vs(unit = "m/s") "Stribeck velocity";
  input Real v_eps(unit = "m/s") "Velocity scale of the tanh regularisation";
  output Real F(unit = "N") "Friction force, positive for positive v";
algorithm
  F := (Fc + (Fs - Fc) * exp(-(v / vs) ^ 2)) * tanh(v / v_eps);
end StribeckFriction;
