"""Synthetic truths and benchmark generators of the mismatch diagnosis, apart from the engine it tests.

truth (the single-axis truth plants, controller and FMU co-simulation), single_axis (concealed-effect bundles,
the tuning and held-out sets, their runner and scores), multi_axis (the coupled-mechanism and Hexapod FMU
truths), multi_axis_truth (the CasADi truth of a multi-axis bundle). Used by the demo, the lab example, the
tests and ``tests/benchmarks``, not by ``diagnose``.
"""
