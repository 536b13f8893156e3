"""Identification of motion-system plants from periodic, swept-sine and closed-loop recordings; tuning.

Plain functions over numpy arrays, one job per module: signals (frequency-domain filtering and period
averaging), leastsquares (Gauss-Markov with statistics), joint (serial-joint regressor), frf (FRF estimation
and model fit), closedloop (projection method), excitation_design (optimal Fourier coefficients of
harness.excitation.fourier_basis), maximum_likelihood (maximum likelihood with filter cut-off), outputerror and
multipleshooting (simulation-error refits), tuning (subpackage: spec, margins, optimisation,
table2, plots, manipulator; controller_fmu writes the result into an FMU), diagnosis (mismatch diagnosis).
"""
