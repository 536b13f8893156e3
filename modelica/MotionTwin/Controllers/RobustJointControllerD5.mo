within MotionTwin.Controllers;
model RobustJointControllerD5 "Robust joint controller with the Cheung and Hung Table 2 design for actuator d5"
  extends MotionTwin.Controllers.RobustJointController(Kp = 0.9122, Ki = 0.0005, Kd = 13.1532, Kv = 2.8185, Ka = 31.04, KL = 10, fp = 320, fc = 690, wl = 355, wh = 400, sigma = 15);
  annotation(__motiontwin(export = true, sampled(period = Ts, method = "tustin")));
end RobustJointControllerD5;
