within MotionTwin.Benchmarks;
model RigidJoint "Rigid linear-motor axis without any added effect, m*der(v) = u - d*v (truth of the parameters-only cases)"
  extends MotionTwin.Effects.JointBase;
equation
  F_effect = 0;
  annotation(__motiontwin(export = true));
end RigidJoint;
