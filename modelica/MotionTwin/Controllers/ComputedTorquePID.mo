within MotionTwin.Controllers;
model ComputedTorquePID "Joint-space computed-torque PID (the controller Cheung and Hung compare against): u = m_hat*(r_ddot + Kd*(r_dot - v_hat) + Kp*(r - q) + Ki*integral(r - q)) + d_hat*v_hat, v_hat a filtered derivative of q"
  parameter Real m_hat(unit = "kg", min = 0) = 2 "Nominal (model) moving mass";
  parameter Real d_hat(unit = "N.s/m", min = 0) = 10 "Nominal (model) viscous damping";
  parameter Real Kp(unit = "1/s2", min = 0) = 47374 "Position gain (default: triple pole at 2*pi*20 rad/s)";
  parameter Real Ki(unit = "1/s3", min = 0) = 1984402 "Integral gain";
  parameter Real Kd(unit = "1/s", min = 0) = 376.99 "Velocity gain";
  parameter Real Tf(unit = "s", min = 1e-9) = 1e-3 "Time constant of the velocity estimate v_hat = s/(Tf*s + 1)*q";
  parameter Real Ts(unit = "s", min = 1e-9) = 5e-4 "Sample period";
  input Real r(unit = "m") "Reference position";
  input Real q(unit = "m") "Measured position";
  input Real r_dot(unit = "m/s") "Reference velocity";
  input Real r_ddot(unit = "m/s2") "Reference acceleration";
  output Real u(unit = "N") "Actuator force command";
  Real xi(unit = "m.s", start = 0, fixed = true) "Integral of the position error";
  Real xq(unit = "m", start = 0, fixed = true) "Low-pass filtered position (velocity estimate state)";
  Real v_hat(unit = "m/s") "Velocity estimate (q - xq)/Tf";
equation
  der(xi) = r - q;
  Tf * der(xq) = q - xq;
  v_hat = (q - xq) / Tf;
  u = m_hat * (r_ddot + Kd * (r_dot - v_hat) + Kp * (r - q) + Ki * xi) + d_hat * v_hat;
  annotation(__motiontwin(export = true, sampled(period = Ts, method = "tustin")), Documentation(info = "Computed torque for the joint model m*der(v) = u - d*v: with exact m_hat, d_hat and v_hat = v the error obeys e''' + Kd*e'' + Kp*e' + Ki*e = 0. Linear (nominal parameters are constants) so it can be Tustin-sampled. Set xq start to the initial position to avoid a velocity kick."));
end ComputedTorquePID;
