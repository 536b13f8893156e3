within MotionTwin.Benchmarks;
model QuadraticDragJoint "Axis with a force outside the diagnosis catalogue: quadratic drag F_effect = c*v*abs(v) (air or fluid drag, cable drag growing with speed)"
  extends MotionTwin.Effects.JointBase;
  parameter Real c(unit = "N.s2/m2", min = 0) = 32 "Quadratic drag coefficient";
equation
  F_effect = c * v * abs(v);
  annotation(__motiontwin(export = true));
end QuadraticDragJoint;
