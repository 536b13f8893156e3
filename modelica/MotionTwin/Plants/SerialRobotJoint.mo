within MotionTwin.Plants;
model SerialRobotJoint "Serial industrial robot joint (Bona and Curatella eqs. (2), (21)-(23)): M*der(w) = tau - k*sin(q + q_off) - f(w), asymmetric viscous and Coulomb friction"
  parameter Real M(unit = "kg.m2", min = 1e-9) = 64.1881 "Equivalent inertia of the joint (Table 3, axis 2 Gamma_zz)";
  parameter Real k(unit = "N.m") = -0.7823 "Gravity torque amplitude of eq. (23) (Table 1, axis 2)";
  parameter Real q_off(unit = "rad") = 0.130899693899575 "Gravity offset angle of eq. (23) (Table 1, axis 2: 7.5 deg)";
  parameter Real beta_vp(unit = "N.m.s/rad", min = 0) = 36.6197 "Viscous friction coefficient for w > 0 (Table 2)";
  parameter Real beta_vn(unit = "N.m.s/rad", min = 0) = 73.0530 "Viscous friction coefficient for w < 0 (Table 2)";
  parameter Real beta_cp(unit = "N.m", min = 0) = 65.4187 "Coulomb friction level for w > 0 (Table 2)";
  parameter Real beta_cn(unit = "N.m", min = 0) = 45.9598 "Coulomb friction level (magnitude) for w < 0 (Table 2)";
  parameter Real w_eps(unit = "rad/s", min = 1e-12) = 1e-3 "Velocity scale of the tanh regularisation of the sign and the direction switch";
  input Real tau(unit = "N.m") "Joint torque command";
  output Real q_meas(unit = "rad") "Measured joint position";
  output Real f_friction(unit = "N.m") "Friction torque (positive opposes positive motion)";
  Real q(unit = "rad", start = 0, fixed = true) "Joint position";
  Real w(unit = "rad/s", start = 0, fixed = true) "Joint velocity";
equation
  der(q) = w;
  M * der(w) = tau - k * sin(q + q_off) - MotionTwin.Effects.AsymmetricFriction(w, beta_vp, beta_vn, beta_cp, beta_cn, w_eps);
  q_meas = q;
  f_friction = MotionTwin.Effects.AsymmetricFriction(w, beta_vp, beta_vn, beta_cp, beta_cn, w_eps);
  annotation(__motiontwin(export = true), Documentation(info = "Eq. (2) is read with the Coulomb term opposing the motion: f = beta_vp*w + beta_cp for w > 0 and f = beta_vn*w - beta_cn for w < 0 (Table 2 lists beta_c- as a positive magnitude). It is smoothed with tanh(w/w_eps), see Effects.AsymmetricFriction. Defaults are axis 2; SerialRobotJointAxis3 has the axis 3 values."));
end SerialRobotJoint;
