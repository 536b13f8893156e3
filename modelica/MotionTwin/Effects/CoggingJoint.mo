within MotionTwin.Effects;
model CoggingJoint "Joint with cogging force of period pole_pitch/n and its second harmonic"
  extends MotionTwin.Effects.JointBase;
  parameter Real pole_pitch(unit = "m", min = 1e-9) = 0.032 "Magnet pole pitch";
  parameter Real n(min = 1) = 3 "Cogging periods per pole pitch";
  parameter Real A1(unit = "N") = 1 "Amplitude of the fundamental";
  parameter Real A2(unit = "N") = 0.3 "Amplitude of the second harmonic";
  parameter Real phase1(unit = "rad") = 0 "Phase of the fundamental at x = 0";
  parameter Real phase2(unit = "rad") = 0 "Phase of the second harmonic at x = 0";
equation
  F_effect = MotionTwin.Effects.CoggingForce(x, pole_pitch, n, A1, A2, phase1, phase2);
end CoggingJoint;
