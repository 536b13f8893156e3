within MotionTwin.Effects;
function RippleForce "Position-periodic force ripple or cogging A*sin(2*pi*x/period + phase)"
  input Real x(unit = "m") "Position";
  input Real A(unit = "N") "Ripple amplitude";
  input Real period(unit = "m") "Spatial period (e.g. the magnet pitch)";
  input Real phase(unit = "rad") "Phase at x = 0";
  output Real F(unit = "N") "Ripple force (enters as an opposing force)";
algorithm
  F := A * sin(6.283185307179586 * x / period + phase);
end RippleForce;
