within MotionTwin.Effects;
model AsymmetricFrictionJoint "Joint with direction-dependent viscous and Coulomb friction (Bona and Curatella eq. (2)); the base viscous d acts in addition"
  extends MotionTwin.Effects.JointBase(d = 0);
  parameter Real beta_vp(unit = "N.s/m", min = 0) = 10 "Viscous coefficient for v > 0";
  parameter Real beta_vn(unit = "N.s/m", min = 0) = 15 "Viscous coefficient for v < 0";
  parameter Real beta_cp(unit = "N", min = 0) = 2 "Coulomb level for v > 0";
  parameter Real beta_cn(unit = "N", min = 0) = 1.5 "Coulomb level (magnitude) for v < 0";
  parameter Real v_eps(unit = "m/s", min = 1e-12) = 1e-3 "Velocity scale of the tanh regularisation";
equation
  F_effect = MotionTwin.Effects.AsymmetricFriction(v, beta_vp, beta_vn, beta_cp, beta_cn, v_eps);
  annotation(__motiontwin(export = true));
end AsymmetricFrictionJoint;
