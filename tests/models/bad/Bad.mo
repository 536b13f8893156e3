model Bad "a syntax error on line 3"
  parameter Real m = 2;
  Real x
equation
  der(x) = -m * x;
end Bad;
