within MotionTwin.Benchmarks;
model PositionFrictionJoint "Axis with a force outside the diagnosis catalogue: friction rising along the stroke F_effect = (Fc0 + k*x)*tanh(v/v_eps) (a preload or a wiper that tightens with position)"
  extends MotionTwin.Effects.JointBase;
  parameter Real Fc0(unit = "N") = 0 "Friction level at x = 0";
  parameter Real k(unit = "N/m") = 3 "Rise of the friction level per metre of travel";
  parameter Real v_eps(unit = "m/s", min = 1e-12) = 5e-3 "Velocity scale of the tanh regularisation";
equation
  F_effect = (Fc0 + k * x) * tanh(v / v_eps);
  annotation(__motiontwin(export = true));
end PositionFrictionJoint;
