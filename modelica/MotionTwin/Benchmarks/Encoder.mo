within MotionTwin.Benchmarks;
model Encoder "Position measurement: the true position plus sensor noise, counted by an incremental encoder, y = resolution*floor((q + noise)/resolution + 0.5)"
  parameter Real resolution(unit = "m", min = 1e-15) = 5e-9 "Encoder count (quantisation step)";
  input Real q(unit = "m") "True position";
  input Real noise(unit = "m") "Sensor noise added before the count (a seeded external signal)";
  output Real y(unit = "m") "Measured position";
equation
  y = resolution * floor((q + noise) / resolution + 0.5);
  annotation(__motiontwin(export = true), Documentation(info = "No states: the output follows its inputs at every communication point (the master reads it when the sampled controller samples). Same rounding as harness.measurement.quantize."));
end Encoder;
