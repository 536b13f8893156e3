within MotionTwin.Effects;
model FrictionDriftJoint "Joint whose Coulomb friction drifts as the axis warms up: Fc(t) = Fc0 + dFc*(1 - exp(-t/tau_drift))"
  extends MotionTwin.Effects.JointBase;
  parameter Real Fc0(unit = "N", min = 0) = 2 "Coulomb friction at t = 0 (cold)";
  parameter Real dFc(unit = "N") = -0.6 "Change of the Coulomb level once warm (negative: lubricant thins)";
  parameter Real tau_drift(unit = "s", min = 1e-9) = 20 "Time constant of the drift";
  parameter Real v_eps(unit = "m/s", min = 1e-12) = 1e-3 "Velocity scale of the tanh regularisation";
  output Real Fc(unit = "N") "Present Coulomb level";
equation
  Fc = Fc0 + dFc * (1 - exp(-time / tau_drift));
  F_effect = MotionTwin.Effects.CoulombFriction(v, Fc, v_eps);
end FrictionDriftJoint;
