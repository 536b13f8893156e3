"""Shared by the diagnosis tests: a bundle read and its nominal model refitted as ``diagnose`` starts; a bundle
copied without its controller."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

from motiontwin.harness.recording import Recording, read_recording, write_recording
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


def without_controller(bundle: Path, target: Path, controller: dict | None = None,
                       keep: tuple[str, ...] = ("u", "q")) -> Path:
    """A copy of ``bundle`` with ``controller`` (None: the field removed) and recordings of the columns ``keep``."""
    shutil.copytree(bundle, target)
    exp = json.loads((target / "experiment.json").read_text())
    exp.pop("controller")
    if controller is not None:
        exp["controller"] = controller
    (target / "experiment.json").write_text(json.dumps(exp))
    for part in exp["recordings"].values():
        rec = read_recording(target / part)
        write_recording(target / part, Recording(rec.time, {c: rec[c] for c in keep},
                                                 {c: rec.units[c] for c in ("time", *keep) if c in rec.units}))
    return target
