within MotionTwin.Controllers;
model StateSpaceController "Generic linear controller der(x) = A*x + B*u, y = C*x + D*u, executed sampled at Ts (Tustin)"
  parameter Integer nx = 1 "Number of states";
  parameter Integer nu = 1 "Number of inputs";
  parameter Integer ny = 1 "Number of outputs";
  parameter Real A[nx, nx] = [0] "State matrix";
  parameter Real B[nx, nu] = [1] "Input matrix";
  parameter Real C[ny, nx] = [10] "Output matrix";
  parameter Real D[ny, nu] = [1] "Feedthrough matrix";
  parameter Real Ts(unit = "s", min = 1e-9) = 5e-4 "Sample period";
  input Real u[nu] "Controller inputs (e.g. the position error)";
  output Real y[ny] "Controller outputs";
  Real x[nx](each start = 0, each fixed = true) "Controller states";
equation
  der(x) = A * x + B * u;
  y = C * x + D * u;
  annotation(__motiontwin(export = true, sampled(period = Ts, method = "tustin")), Documentation(info = "Default: the PI controller y = (1 + 10/s)*u. A discrete-time (A, B, C, D) as in Modelica.Blocks.Discrete.StateSpace corresponds to the continuous matrices obtained by inverting the Tustin map (e.g. scipy/python-control d2c with method bilinear)."));
end StateSpaceController;
