within MotionTwin.Effects;
function SaturatedForce "Actuator force limited to +-Fmax (current limit of the amplifier), corners rounded by eps"
  input Real u(unit = "N") "Commanded force";
  input Real Fmax(unit = "N") "Force limit";
  input Real eps(unit = "N") "Rounding of the corners";
  output Real F(unit = "N") "Delivered force: u for |u| < Fmax, +-Fmax beyond";
algorithm
  F := 0.5 * (sqrt((u + Fmax) ^ 2 + eps ^ 2) - sqrt((u - Fmax) ^ 2 + eps ^ 2));
end SaturatedForce;
