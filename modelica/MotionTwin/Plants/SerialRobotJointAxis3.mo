within MotionTwin.Plants;
model SerialRobotJointAxis3 "COMAU Smart S2 axis 3 (Bona and Curatella Tables 1-3)"
  extends MotionTwin.Plants.SerialRobotJoint(M = 7.4838, k = 0.4097, q_off = 0.436332312998582, beta_vp = 10.6964, beta_vn = 11.5955, beta_cp = 13.3809, beta_cn = 11.3347);
  annotation(__motiontwin(export = true));
end SerialRobotJointAxis3;
