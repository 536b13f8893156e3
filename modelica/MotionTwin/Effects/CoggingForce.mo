within MotionTwin.Effects;
function CoggingForce "Cogging force of a permanent-magnet motor tied to its pole pitch: harmonics k = 1, 2 of the cogging order n per pole pitch, A1*sin(2*pi*n*x/pole_pitch + phase1) + A2*sin(4*pi*n*x/pole_pitch + phase2)"
  input Real x(unit = "m") "Position";
  input Real pole_pitch(unit = "m") "Magnet pole pitch";
  input Real n "Cogging periods per pole pitch (e.g. slots per pole for an iron-core linear motor)";
  input Real A1(unit = "N") "Amplitude of the fundamental cogging harmonic";
  input Real A2(unit = "N") "Amplitude of the second cogging harmonic";
  input Real phase1(unit = "rad") "Phase of the fundamental at x = 0";
  input Real phase2(unit = "rad") "Phase of the second harmonic at x = 0";
  output Real F(unit = "N") "Cogging force (enters as an opposing force)";
protected
  Real theta(unit = "rad") "Cogging angle 2*pi*n*x/pole_pitch";
algorithm
  theta := 6.283185307179586 * n * x / pole_pitch;
  F := A1 * sin(theta + phase1) + A2 * sin(2 * theta + phase2);
end CoggingForce;
