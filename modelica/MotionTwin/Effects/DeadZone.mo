within MotionTwin.Effects;
function DeadZone "Smoothed dead zone of half-width b: 0 for |delta| < b, delta - b above, delta + b below (the backlash gap of a transmission)"
  input Real delta(unit = "m") "Relative displacement across the gap";
  input Real b(unit = "m") "Half-width of the gap (total backlash 2*b)";
  input Real eps(unit = "m") "Rounding of the corners (error at the corners eps/2, vanishing away from them)";
  output Real y(unit = "m") "Deflection of the transmission beyond the gap";
algorithm
  y := delta + 0.5 * (sqrt((delta - b) ^ 2 + eps ^ 2) - sqrt((delta + b) ^ 2 + eps ^ 2));
end DeadZone;
