"""Linearise an FMU at its initial point from its own directional derivatives (Model Exchange interface).

The FMU's ``GetDirectionalDerivative`` gives the columns of ``[A B; C D] = d[dx; y]/d[x; u]``; the result
is a python-control ``StateSpace`` in the FMU's units, states in ModelStructure order.
"""
from __future__ import annotations

from pathlib import Path
from typing import Mapping

import control
import numpy as np
from fmpy.fmi2 import FMU2Model
from fmpy.fmi3 import FMU3Model

from motiontwin.fmus.archive import read_description
from motiontwin.harness.fmu_instance import extracted_fmu


def linearize(fmu: str | Path, inputs: list[str], outputs: list[str],
              start_values: Mapping[str, float] | None = None) -> control.StateSpace:
    """``StateSpace`` of ``fmu`` from ``inputs`` to ``outputs`` at t = 0 after initialisation."""
    md = read_description(fmu)
    if not md.modelExchange:  # (fmpy 0.3.32 does not read FMI 3.0's providesDirectionalDerivatives flag)
        raise ValueError(f"{fmu}: no Model Exchange interface")
    vr = {v.name: v.valueReference for v in md.modelVariables}
    missing = [n for n in [*inputs, *outputs] if n not in vr]
    if missing:
        raise ValueError(f"{fmu}: no variables {missing}; inputs are "
                         f"{[v.name for v in md.modelVariables if v.causality == 'input']}")
    states = [d.variable.derivative.valueReference for d in md.derivatives]
    derivatives = [d.variable.valueReference for d in md.derivatives]
    known = states + [vr[n] for n in inputs]
    unknown = derivatives + [vr[n] for n in outputs]
    fmi3 = md.fmiVersion != "2.0"
    cls = FMU3Model if fmi3 else FMU2Model
    model = cls(guid=md.guid, unzipDirectory=extracted_fmu(fmu),
                modelIdentifier=md.modelExchange.modelIdentifier, instanceName="linearize")
    model.instantiate()
    try:
        if not fmi3:
            model.setupExperiment(startTime=0.0)
        if start_values:
            names = list(start_values)
            values = [float(start_values[n]) for n in names]
            (model.setFloat64 if fmi3 else model.setReal)([vr[n] for n in names], values)
        model.enterInitializationMode()
        model.exitInitializationMode()
        columns = []
        for j in range(len(known)):
            seed = [0.0] * len(known)
            seed[j] = 1.0
            columns.append(model.getDirectionalDerivative(unknown, known, seed))
        model.terminate()
    finally:
        model.freeInstance()
    jac = np.array(columns, dtype=float).T
    n = len(states)
    return control.ss(jac[:n, :n], jac[:n, n:], jac[n:, :n], jac[n:, n:], inputs=inputs, outputs=outputs)
