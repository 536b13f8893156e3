"""Mismatch diagnosis (issue 7): locate where a recording disagrees with the nominal model, name the
missing physics from a fixed vocabulary, add it to the Modelica model, refit, rebuild the FMU and show the
validation fit improve. Entry points: :func:`diagnose` and :func:`main` (``motiontwin diagnose``)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from motiontwin.fmus.limits import check_size, load_json

from motiontwin.ident.diagnosis.bundle import BundleError, make_bundle, read_bundle
from motiontwin.ident.diagnosis.engine import diagnose, diagnose_bundle, diagnose_bundle_object
from motiontwin.ident.diagnosis.pipeline import Diagnosis
from motiontwin.ident.startvalues import DivergenceError

__all__ = ["BundleError", "Diagnosis", "DivergenceError", "check_sizes", "diagnose", "diagnose_bundle", "main",
           "make_bundle", "read_bundle"]


def run(bundle: str, out: str, quiet: bool = False, allow_outside_paths: bool = False) -> int:
    """Diagnose ``bundle`` into ``out``; print a one-line summary; exit code 0, or 2 on a bad bundle (files
    named in its experiment.json must lie inside it unless ``allow_outside_paths``)."""
    progress = None if quiet else (lambda msg: print(msg, file=sys.stderr, flush=True))
    try:
        check_sizes(Path(bundle))
        doc = diagnose_bundle_object(read_bundle(bundle, allow_outside_paths), progress).write(out)
    except BundleError as exc:
        print(f"motiontwin diagnose: bad bundle: {exc}", file=sys.stderr)
        return 2
    except DivergenceError as exc:
        print(f"motiontwin diagnose: {exc}", file=sys.stderr)
        return 2
    from motiontwin.ident.diagnosis.bounds import at_bound_text
    from motiontwin.ident.diagnosis.report import unexplained_text

    unexplained, unconfirmed = doc.get("unexplained"), doc.get("not_confirmed")
    names = ", ".join(_on_axis(e["name"], e) for e in doc["effects"]) \
        or ("none" if unexplained or unconfirmed else "none (only parameters were off)")
    if unconfirmed:
        names += "; not confirmed (the validation recording does not exercise it): " + ", ".join(
            _on_axis(c["effect"], c) for c in unconfirmed)
    if unexplained:
        names += f"; {unexplained_text(unexplained)}"
    val = doc["validation"]
    units = doc.get("units", {})
    axis_unit = {axis: units.get(axis, {}).get("position", "m") for axis in val.get("per_axis", {})}
    unit = units.get("position") or ("rad" if axis_unit and set(axis_unit.values()) == {"rad"} else "m")
    per_axis = "".join(f"; {axis} {_length(v['nominal_rms'], axis_unit[axis])} -> "
                       f"{_length(v['augmented_rms'], axis_unit[axis])}" for axis, v in val.get("per_axis", {}).items())
    bound = at_bound_text(doc.get("at_bound", {}))
    print(f"effects: {names}; validation RMS {_length(val['nominal_rms'], unit)} -> "
          f"{_length(val['augmented_rms'], unit)}"
          f"{per_axis}{f'; at bound: {bound}' if bound else ''}; report: {out}/report.md")
    return 0


def check_sizes(bundle: Path) -> None:
    """experiment.json (a folder, size, UTF-8, nesting) and the plant's Modelica file (size) checked before the
    bundle reader reads them (the recordings' sizes and rows are checked by their reader)."""
    experiment = bundle / "experiment.json"
    if not experiment.exists():
        return
    doc = load_json(experiment, BundleError)
    plant = doc.get("plant") if isinstance(doc, dict) else None
    modelica = plant.get("modelica") if isinstance(plant, dict) else None
    if isinstance(modelica, str) and (bundle / modelica).is_file():
        check_size(bundle / modelica, "text", BundleError)


def _on_axis(name: str, entry: dict) -> str:
    """An effect's name, with the axis it acts on when the entry has one (several axes)."""
    return f"{name} on {entry['axis']}" if "axis" in entry else name


def _length(value: float | None, unit: str) -> str:
    """A position error (m or rad) for the summary line; a diverged (None) value says so."""
    return "diverged" if value is None else f"{value:.3g} {unit}"


def main(argv: list[str] | None = None) -> int:
    """``python -m motiontwin.ident.diagnosis BUNDLE_DIR --out OUT_DIR`` (the same as ``motiontwin diagnose``)."""
    from motiontwin.ident.bundleformat import BUNDLE_FORMAT

    parser = argparse.ArgumentParser(prog="motiontwin diagnose", epilog=BUNDLE_FORMAT,
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     description="Diagnose the mismatch between a nominal model and a recording.")
    parser.add_argument("bundle", help="bundle directory holding experiment.json")
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument("--quiet", action="store_true", help="do not print progress")
    args = parser.parse_args(argv)
    return run(args.bundle, args.out, args.quiet)


if __name__ == "__main__":
    sys.exit(main())
