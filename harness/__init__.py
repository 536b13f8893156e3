"""Co-simulation harness: closed loops of FMUs, excitation experiments, recordings, the motiontwin CLI."""
