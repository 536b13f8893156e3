within MotionTwin.Benchmarks;
model LoopController "The benchmark's sampled two-state controller u[k] = C*x[k] + D*[r[k]; q[k]], x[k+1] = A*x[k] + B*[r[k]; q[k]] (e.g. a Tustin-discretised PID on r - q); A, B, C, D are set as parameter values"
  extends MotionTwin.Controllers.DiscreteStateSpaceController(nx = 2, nu = 2, ny = 1, A = [1, 0; 0, 1], B = [0, 0; 0, 0], C = [0, 0], D = [1, -1]);
  annotation(__motiontwin(export = true, sampled(period = Ts, method = "discrete")));
end LoopController;
