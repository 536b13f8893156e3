within MotionTwin.Effects;
model LuGreJoint "Joint with LuGre friction (pre-sliding hysteresis, Stribeck effect); F_effect is the LuGre force, its viscous part included"
  extends MotionTwin.Effects.JointBase(d = 0);
  parameter Real Fc(unit = "N", min = 0) = 2 "Coulomb (sliding) friction level";
  parameter Real Fs(unit = "N", min = 0) = 3 "Static (breakaway) friction level, Fs >= Fc";
  parameter Real vs(unit = "m/s", min = 1e-12) = 5e-3 "Stribeck velocity";
  parameter Real sigma0(unit = "N/m", min = 0) = 1e6 "Bristle stiffness";
  parameter Real sigma1(unit = "N.s/m", min = 0) = 300 "Bristle damping";
  parameter Real sigma2(unit = "N.s/m", min = 0) = 10 "Viscous friction coefficient";
  Real z(unit = "m", start = 0, fixed = true) "Mean bristle deflection";
equation
  (F_effect, der(z)) = MotionTwin.Effects.LuGreFriction(v, z, Fc, Fs, vs, sigma0, sigma1, sigma2);
  annotation(Documentation(info = "Steady sliding at velocity v: z = sign(v)*g(v)/sigma0 and F = g(v)*sign(v) + sigma2*v, the Stribeck curve. Pre-sliding from rest: F = sigma0*(x - x0) for displacements small against g/sigma0. JointBase's viscous d is set to 0: sigma2 is the viscous coefficient."));
end LuGreJoint;
