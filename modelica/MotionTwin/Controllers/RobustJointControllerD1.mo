within MotionTwin.Controllers;
model RobustJointControllerD1 "Robust joint controller with the Cheung and Hung Table 2 design for actuator d1"
  extends MotionTwin.Controllers.RobustJointController(Kp = 0.7987, Ki = 0.003, Kd = 15.1038, Kv = 4.8751, Ka = 60.411, KL = 10, fp = 305, fc = 533, wl = 380, wh = 400, sigma = 15);
  annotation(__motiontwin(export = true, sampled(period = Ts, method = "tustin")));
end RobustJointControllerD1;
