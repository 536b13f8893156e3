"""Co-simulation harness: closed loops of FMUs (master, system files), one run -> a recording (simulation),
excitation experiments, recordings, sweeps, regression suites."""
