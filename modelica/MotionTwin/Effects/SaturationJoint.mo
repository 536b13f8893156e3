within MotionTwin.Effects;
model SaturationJoint "Joint whose actuator saturates at +-Fmax: F_effect = u - SaturatedForce(u)"
  extends MotionTwin.Effects.JointBase;
  parameter Real Fmax(unit = "N", min = 0) = 20 "Actuator force limit";
  parameter Real eps(unit = "N", min = 1e-12) = 1e-3 "Rounding of the saturation corners";
equation
  F_effect = u - MotionTwin.Effects.SaturatedForce(u, Fmax, eps);
end SaturationJoint;
