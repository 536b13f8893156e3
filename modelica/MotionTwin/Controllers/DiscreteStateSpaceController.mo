within MotionTwin.Controllers;
model DiscreteStateSpaceController "Discrete-time linear controller x[k+1] = A*x[k] + B*u[k], y[k] = C*x[k] + D*u[k] at Ts, as Modelica.Blocks.Discrete.StateSpace"
  parameter Integer nx = 1 "Number of states";
  parameter Integer nu = 1 "Number of inputs";
  parameter Integer ny = 1 "Number of outputs";
  parameter Real A[nx, nx] = [1] "Discrete state matrix";
  parameter Real B[nx, nu] = [5e-3] "Discrete input matrix";
  parameter Real C[ny, nx] = [1] "Output matrix";
  parameter Real D[ny, nu] = [1] "Feedthrough matrix";
  parameter Real Ts(unit = "s", min = 1e-9) = 5e-4 "Sample period";
  input Real u[nu] "Controller inputs, sampled at k*Ts";
  output Real y[ny] "Controller outputs, held between samples";
  Real x[nx](each start = 0, each fixed = true) "Controller states x[k]";
equation
  der(x) = A * x + B * u "read as x[k+1] (method = discrete)";
  y = C * x + D * u;
  annotation(__motiontwin(export = true, sampled(period = Ts, method = "discrete")), Documentation(info = "The front end has no sample/pre; with sampled(method=discrete) the pipeline reads der(x) as the state at the next sample, so A, B, C, D are used as the discrete-time matrices unchanged. Default: a discrete PI, y[k] = u[k] + x[k], x[k+1] = x[k] + 5e-3*u[k]."));
end DiscreteStateSpaceController;
