within MotionTwin.Controllers;
model RobustJointControllerD7 "Robust joint controller with the Cheung and Hung Table 2 design for actuator d7"
  extends MotionTwin.Controllers.RobustJointController(Kp = 0.8438, Ki = 0.01, Kd = 15.4567, Kv = 9.6264, Ka = 49.411, KL = 10, fp = 305, fc = 617, wl = 370, wh = 300, sigma = 30);
  annotation(__motiontwin(export = true, sampled(period = Ts, method = "tustin")));
end RobustJointControllerD7;
