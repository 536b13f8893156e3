within MotionTwin.Effects;
model CoulombJoint "Joint with smoothed Coulomb friction F_effect = Fc*tanh(v/v_eps)"
  extends MotionTwin.Effects.JointBase;
  parameter Real Fc(unit = "N", min = 0) = 2 "Coulomb friction level";
  parameter Real v_eps(unit = "m/s", min = 1e-12) = 1e-3 "Velocity scale of the tanh regularisation";
equation
  F_effect = MotionTwin.Effects.CoulombFriction(v, Fc, v_eps);
  annotation(__motiontwin(export = true));
end CoulombJoint;
