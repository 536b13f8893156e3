within MotionTwin.Plants;
model SerialRobotJointAxis2 "COMAU Smart S2 axis 2 (Bona and Curatella Tables 1-3)"
  extends MotionTwin.Plants.SerialRobotJoint(M = 64.1881, k = -0.7823, q_off = 0.130899693899575, beta_vp = 36.6197, beta_vn = 73.0530, beta_cp = 65.4187, beta_cn = 45.9598);
  annotation(__motiontwin(export = true));
end SerialRobotJointAxis2;
