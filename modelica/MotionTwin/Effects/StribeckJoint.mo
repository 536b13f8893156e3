within MotionTwin.Effects;
model StribeckJoint "Joint with smoothed Stribeck friction F_effect = (Fc + (Fs - Fc)*exp(-(v/vs)^2))*tanh(v/v_eps)"
  extends MotionTwin.Effects.JointBase;
  parameter Real Fc(unit = "N", min = 0) = 2 "Coulomb (sliding) friction level";
  parameter Real Fs(unit = "N", min = 0) = 3 "Static (breakaway) friction level";
  parameter Real vs(unit = "m/s", min = 1e-12) = 0.01 "Stribeck velocity";
  parameter Real v_eps(unit = "m/s", min = 1e-12) = 1e-4 "Velocity scale of the tanh regularisation";
equation
  F_effect = MotionTwin.Effects.StribeckFriction(v, Fc, Fs, vs, v_eps);
  annotation(__motiontwin(export = true));
end StribeckJoint;
