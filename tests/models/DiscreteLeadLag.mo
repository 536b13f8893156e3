model DiscreteLeadLag "A two-state discrete controller through the library's DiscreteStateSpaceController"
  extends MotionTwin.Controllers.DiscreteStateSpaceController(nx = 2, nu = 1, ny = 1,
    A = [0.9, 0.05; -0.02, 0.7], B = [0.3; 1.0], C = [2.0, -1.0], D = [0.5], Ts = 1e-3);
  annotation(__motiontwin(sampled(period = Ts, method = "discrete")));
end DiscreteLeadLag;
