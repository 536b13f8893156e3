within MotionTwin.Effects;
model RippleJoint "Joint with position-periodic force ripple (cogging) F_effect = A*sin(2*pi*x/period + phase)"
  extends MotionTwin.Effects.JointBase;
  parameter Real A(unit = "N") = 1 "Ripple amplitude";
  parameter Real period(unit = "m", min = 1e-9) = 0.024 "Spatial period (magnet pitch)";
  parameter Real phase(unit = "rad") = 0 "Phase at x = 0";
equation
  F_effect = MotionTwin.Effects.RippleForce(x, A, period, phase);
  annotation(__motiontwin(export = true));
end RippleJoint;
