within MotionTwin.Effects;
function LuGreFriction "LuGre friction force sigma0*z + sigma1*der(z) + sigma2*v with bristle dynamics der(z) = v - sigma0*abs(v)/g(v)*z and g(v) = Fc + (Fs - Fc)*exp(-(v/vs)^2); returns F and der(z) (Dahl's model is sigma1 = sigma2 = 0, Fs = Fc)"
  input Real v(unit = "m/s") "Sliding velocity";
  input Real z(unit = "m") "Mean bristle deflection";
  input Real Fc(unit = "N") "Coulomb (sliding) friction level";
  input Real Fs(unit = "N") "Static (breakaway) friction level, Fs >= Fc";
  input Real vs(unit = "m/s") "Stribeck velocity";
  input Real sigma0(unit = "N/m") "Bristle stiffness (pre-sliding stiffness)";
  input Real sigma1(unit = "N.s/m") "Bristle damping";
  input Real sigma2(unit = "N.s/m") "Viscous friction coefficient";
  output Real F(unit = "N") "Friction force, opposes v in steady sliding";
  output Real dz(unit = "m/s") "Time derivative of z";
algorithm
  dz := v - sigma0 * abs(v) / (Fc + (Fs - Fc) * exp(-(v / vs) ^ 2)) * z;
  F := sigma0 * z + sigma1 * dz + sigma2 * v;
end LuGreFriction;
