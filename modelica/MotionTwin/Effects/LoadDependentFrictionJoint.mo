within MotionTwin.Effects;
model LoadDependentFrictionJoint "Joint whose Coulomb friction grows with the drive force: F_effect = (Fc0 + mu*|u|)*tanh(v/v_eps)"
  extends MotionTwin.Effects.JointBase;
  parameter Real Fc0(unit = "N", min = 0) = 0.5 "Friction level without load";
  parameter Real mu(min = 0) = 0.05 "Friction rise per newton of drive force";
  parameter Real v_eps(unit = "m/s", min = 1e-12) = 1e-3 "Velocity scale of the tanh regularisation";
equation
  F_effect = MotionTwin.Effects.LoadDependentFriction(v, u, Fc0, mu, v_eps);
end LoadDependentFrictionJoint;
