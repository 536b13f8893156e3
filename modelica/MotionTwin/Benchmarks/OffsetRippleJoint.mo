within MotionTwin.Benchmarks;
model OffsetRippleJoint "Axis with two effects at once: a constant offset force F0 and a position-periodic force ripple A*sin(2*pi*x/period + phase)"
  extends MotionTwin.Effects.JointBase;
  parameter Real F0(unit = "N") = 1 "Constant opposing force (gravity or cable preload)";
  parameter Real A(unit = "N") = 0.5 "Ripple amplitude";
  parameter Real period(unit = "m", min = 1e-9) = 0.012 "Spatial period of the ripple (magnet pitch)";
  parameter Real phase(unit = "rad") = 0 "Ripple phase at x = 0";
equation
  F_effect = F0 + MotionTwin.Effects.RippleForce(x, A, period, phase);
  annotation(__motiontwin(export = true));
end OffsetRippleJoint;
