within MotionTwin;
package Benchmarks "Truth models of the diagnosis benchmark (ident.diagnosis.benchmark): plants with effects the nominal rigid axis leaves out, the encoder that quantises the measured position, and the sampled controller of the benchmark loop; co-simulated as FMUs by the harness"
end Benchmarks;
