within MotionTwin.Effects;
function DeadZoneSlope "Derivative of DeadZone with respect to delta: 0 inside the gap, 1 in contact (the contact indicator)"
  input Real delta(unit = "m") "Relative displacement across the gap";
  input Real b(unit = "m") "Half-width of the gap";
  input Real eps(unit = "m") "Rounding of the corners";
  output Real s "d DeadZone / d delta, between 0 and 1";
algorithm
  s := 1 + 0.5 * ((delta - b) / sqrt((delta - b) ^ 2 + eps ^ 2) - (delta + b) / sqrt((delta + b) ^ 2 + eps ^ 2));
end DeadZoneSlope;
