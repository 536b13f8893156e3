"""Shared by the diagnosis tests: a bundle read and its nominal model refitted as ``diagnose`` starts."""
from __future__ import annotations

from pathlib import Path

from motiontwin.ident import outputerror
from motiontwin.ident.diagnosis import effects as effect_models
from motiontwin.ident.diagnosis import noise
from motiontwin.ident.diagnosis.bundle import Bundle, read_bundle
from motiontwin.ident.diagnosis.locate import context
from motiontwin.ident.diagnosis.nominal import fit_nominal, nominal_start
from motiontwin.ident.diagnosis.structure import LoopCache, ModelFit


def refitted_nominal(folder: Path, process_noise: bool = False
                     ) -> tuple[Bundle, ModelFit, outputerror.Weights, effect_models.Context]:
    """The bundle in ``folder``, its refitted nominal model, weights and context (with ``process_noise`` the
    bundle's process force noise estimated first, as the diagnosis does before its screening)."""
    bundle = read_bundle(folder)
    bundle.cache = LoopCache()
    bundle.start = nominal_start(bundle)
    nominal, weights = fit_nominal(bundle)
    if process_noise:
        bundle.process_noise = noise.of_bundle(bundle, nominal.fit.values, weights.sigma_q)
    return bundle, nominal, weights, context(bundle, nominal)
