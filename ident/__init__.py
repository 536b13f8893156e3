"""Identification of motion-system plants from periodic, swept-sine and closed-loop recordings.

Plain functions over numpy arrays, one job per module: signals (frequency-domain filtering and period
averaging), leastsquares (Gauss-Markov with statistics), joint (serial-joint regressor), trajectory
(Fourier excitation), frf (FRF estimation and model fit), closedloop (projection method),
excitation_design (optimal Fourier coefficients), ml (maximum likelihood with filter cut-off).
"""
