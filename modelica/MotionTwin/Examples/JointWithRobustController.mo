within MotionTwin.Examples;
model JointWithRobustController "Cheung joint-space plant (CheungJoint) in closed loop with the robust controller, controller evaluated in continuous time"
  MotionTwin.Plants.CheungJoint plant "Joint-space plant with one resonance/antiresonance pair";
  MotionTwin.Controllers.RobustJointController controller(Kp = 4e4, Ki = 4e5, Kd = 300, tau = 2e-4, KL = 0.6, Kv = 10, Ka = 1) "Robust controller re-tuned for the 1 kg default plant (about 35 Hz bandwidth)";
  input Real r(unit = "m") "Reference position";
  input Real r_dot(unit = "m/s") "Reference velocity";
  input Real r_ddot(unit = "m/s2") "Reference acceleration";
  input Real r_dddot(unit = "m/s3") "Reference jerk";
  output Real q(unit = "m") "Measured joint position";
  output Real u(unit = "N") "Actuator force";
equation
  controller.r = r;
  controller.r_dot = r_dot;
  controller.r_ddot = r_ddot;
  controller.r_dddot = r_dddot;
  controller.q = plant.q;
  plant.u = controller.u;
  q = plant.q;
  u = controller.u;
  annotation(__motiontwin(export = true));
end JointWithRobustController;
