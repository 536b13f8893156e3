within MotionTwin.Effects;
model DelayedInputJoint "Joint whose actuator force is delayed by T; exp(-s*T) is replaced by the second-order Pade approximant (1 - s*T/2 + (s*T)^2/12)/(1 + s*T/2 + (s*T)^2/12)"
  extends MotionTwin.Effects.JointBase;
  parameter Real T(unit = "s", min = 1e-9) = 5e-4 "Input time delay (must be > 0)";
  Real p1(unit = "N", start = 0, fixed = true) "First Pade state";
  Real a(unit = "N", start = 0, fixed = true) "Second Pade state, u - u_delayed";
  Real u_delayed(unit = "N") "Delayed actuator force acting on the mass";
equation
  T * der(p1) = a;
  T * der(a) = 12 * (u - p1) - 6 * a;
  u_delayed = u - a;
  F_effect = u - u_delayed;
  annotation(__motiontwin(export = true), Documentation(info = "Realisation: Pade(2,2) = 1 - s*T/(1 + s*T/2 + (s*T)^2/12); with a = u - u_delayed: T*der(p1) = a, T*der(a) = 12*(u - p1) - 6*a. Phase error below 1 deg up to omega*T = 1.5 rad; unit gain at all frequencies."));
end DelayedInputJoint;
