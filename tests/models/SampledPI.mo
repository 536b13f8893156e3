model SampledPI "PI controller with a first-order derivative filter, executed sampled at Ts (Tustin)"
  parameter Real Kp = 2 "proportional gain";
  parameter Real Ki(unit = "s-1") = 30 "integral gain";
  parameter Real Kd(unit = "s") = 0.01 "derivative gain";
  parameter Real tau(unit = "s", min = 1e-9) = 0.002 "derivative filter time constant";
  parameter Real Ts(unit = "s", min = 1e-9) = 0.001 "sample period";
  input Real e "control error";
  output Real y "controller output";
  Real xi(start = 0) "integral state";
  Real xd(start = 0) "derivative filter state";
equation
  der(xi) = Ki * e;
  tau * der(xd) = e - xd;
  y = Kp * e + xi + Kd * (e - xd) / tau;
  annotation(__motiontwin(sampled(period = Ts, method = "tustin")));
end SampledPI;
