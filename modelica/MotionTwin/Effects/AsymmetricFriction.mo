within MotionTwin.Effects;
function AsymmetricFriction "Direction-dependent viscous + Coulomb friction (Bona and Curatella eq. (2)), smoothed: positive branch beta_vp*v + beta_cp, negative branch beta_vn*v - beta_cn"
  input Real v(unit = "m/s") "Velocity (rad/s for a revolute joint)";
  input Real beta_vp(unit = "N.s/m") "Viscous coefficient for v > 0";
  input Real beta_vn(unit = "N.s/m") "Viscous coefficient for v < 0";
  input Real beta_cp(unit = "N") "Coulomb level for v > 0";
  input Real beta_cn(unit = "N") "Coulomb level (magnitude) for v < 0";
  input Real v_eps(unit = "m/s") "Velocity scale of the tanh regularisation";
  output Real F(unit = "N") "Friction force, opposes v, zero at v = 0";
protected
  Real t "tanh(v/v_eps)";
  Real sp "Weight of the positive branch, (1 + t)/2";
algorithm
  t := tanh(v / v_eps);
  sp := (1 + t) / 2;
  F := v * (beta_vp * sp + beta_vn * (1 - sp)) + t * (beta_cp * sp + beta_cn * (1 - sp));
end AsymmetricFriction;
