within MotionTwin.Controllers;
model RobustJointControllerD3 "Robust joint controller with the Cheung and Hung Table 2 design for actuator d3"
  extends MotionTwin.Controllers.RobustJointController(Kp = 0.7229, Ki = 0.001, Kd = 12.8725, Kv = 5.5518, Ka = 32.757, KL = 10, fp = 316, fc = 716, wl = 446, wh = 300, sigma = 25);
  annotation(__motiontwin(export = true, sampled(period = Ts, method = "tustin")));
end RobustJointControllerD3;
