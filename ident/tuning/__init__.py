"""Tuning of the Cheung & Hung robust joint controller (eqs. 9-13) against eqs. (14)-(18), on the discrete loop.

The loop and its margins are described in ``ident.tuning.margins``.

The method in modules, one concern each (this module gathers their public names):

- ``ident.tuning.spec``: the spec, margins and result types, the constraints a design misses, plant sets as text;
- ``ident.tuning.margins``: the controller law (the FMU's own matrices), the sampled loop and its margins
  (GM, PM, CLBW, Ms, disk margin, tau_cl);
- ``ident.tuning.optimisation``: :func:`tune` (differential evolution, Nelder-Mead, SLSQP) and the
  feedforward fit of eq. (12);
- ``ident.tuning.table2``: the paper's Table 2 designs rescaled onto our plant;
- ``ident.controller_fmu``: the result written into a controller FMU;
- ``ident.tuning.plots`` (figures) and ``ident.tuning.manipulator`` (per-actuator design on the coupled FMU).

Units: SI. Plant K in m/(N s^2) (1/mass), alpha and omega in rad/s; controller gains in N/m, N/(m s), N s/m;
controller frequencies fc, fp, wl, wh in Hz (as in Table 2 and the FMU); Ts in s; margins in dB and deg;
bandwidth in Hz; tau_cl and tau_max in s.
"""
from __future__ import annotations

from motiontwin.ident.tuning.margins import (check_plant, closed_loop_modes, controller_defaults,
                                             controller_matrices, controller_system, discrete_plant,
                                             disk_margin_from_response, feedforward_path_response, frequency_grid,
                                             loop_margins, loop_system, margins_from_response, position_sets,
                                             slowest_time_constant)
from motiontwin.ident.tuning.optimisation import DESIGN_BOUNDS, feedforward_gains, tune
from motiontwin.ident.tuning.spec import (CONTROLLER_CLASS, DESIGN_NAMES, PLANT_CLASS, FeedforwardFit,
                                          InfeasibleSpecError, LoopMargins, TuningError, TuningResult, TuningSpec,
                                          cheung_joint_defaults, format_margins, joint_model_from_fields,
                                          violations)
from motiontwin.ident.tuning.table2 import (TABLE2, TABLE2_READINGS, comparison_markdown, format_comparison,
                                            rescale_to_bandwidth, table2_comparison, table2_parameters)

__all__ = [
    "CONTROLLER_CLASS", "TuningError", "InfeasibleSpecError", "TuningSpec", "LoopMargins", "TuningResult",
    "DESIGN_BOUNDS", "TABLE2", "TABLE2_READINGS", "controller_defaults", "controller_matrices", "controller_system",
    "check_plant", "discrete_plant", "loop_system", "margins_from_response", "loop_margins", "position_sets", "tune",
    "rescale_to_bandwidth", "table2_parameters", "table2_comparison", "format_comparison", "format_margins",
    "violations", "frequency_grid", "DESIGN_NAMES", "PLANT_CLASS", "joint_model_from_fields", "cheung_joint_defaults",
    "FeedforwardFit", "feedforward_gains", "feedforward_path_response", "comparison_markdown", "closed_loop_modes",
    "slowest_time_constant", "disk_margin_from_response",
]
