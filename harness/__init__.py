"""Co-simulation harness: closed loops of FMUs (master, system files), one run -> a recording (simulation),
excitation experiments, recordings, sweeps, regression suites."""

#: environment variables that set a BLAS thread count: every motiontwin process runs one BLAS thread unless the
#: user sets one of them (the ``motiontwin`` command sets them before numpy loads; the diagnosis limits its own
#: run when called from Python). The work is many small least-squares problems that scale out by worker
#: processes (sweep, screening, fleet), while OpenBLAS's own threads spin.
BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")
