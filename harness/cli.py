"""The ``motiontwin`` console script: one entry point, one subcommand per step of the data flow."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Callable

import numpy as np


def _build(args: argparse.Namespace) -> int:
    from fmus import build

    classes = list(args.classes)
    if args.all:
        classes += build.exported_classes(args.modelica)
    if not classes:
        print("motiontwin build: name at least one Modelica class, or --all", file=sys.stderr)
        return 2
    for fmu in build.build(classes, args.modelica, args.out, tuple(args.fmi)):
        print(fmu.path)
    return 0


def _demo(args: argparse.Namespace) -> int:
    from harness import demo

    demo.run(Path(args.out))
    return 0


def _excite(args: argparse.Namespace) -> int:
    from harness import excitation, recording

    rec = excitation.experiment_recording(excitation.load_experiment(args.experiment))
    for path in recording.write_recording(args.out, rec):
        print(path)
    if args.mat:
        print(recording.write_mat(args.out.with_suffix(".mat"), rec))
    return 0


def _log_recording(logs: dict[str, np.ndarray], group: str | None, meta: dict, **provenance: object):
    """The recording of one log group of a master run (units and FMUs from ``meta``)."""
    from harness import recording

    group = group or next(iter(logs))
    if group not in logs:
        raise ValueError(f"log group {group!r}: the system logs {sorted(logs)}")
    log = logs[group]
    columns = {name: log[name] for name in log.dtype.names if name != "time"}
    units = {name: meta["units"].get(name) or "" for name in columns}
    return recording.make_recording(log["time"], columns, units, sample_time=float(log["time"][1] - log["time"][0]),
                                    fmus=meta["fmus"], **provenance)


def _run(args: argparse.Namespace) -> int:
    from harness import recording
    from harness.inputs import input_from_spec
    from harness.master import Master

    inputs = dict(input_from_spec(spec) for spec in args.input)
    with Master(args.system) as master:
        logs = master.run(inputs=inputs, stop_time=args.stop_time)
        meta = master.metadata()
    rec = _log_recording(logs, args.log, meta, excited={"inputs": args.input},
                         metadata={"system": str(args.system), "order": meta["order"]})
    for path in recording.write_recording(args.out, rec):
        print(path)
    return 0


def _sweep(args: argparse.Namespace) -> int:
    import json
    import time

    from harness import recording, sweep
    from harness.executor import make_executor
    from harness.master import master_for

    plan = sweep.load_sweep(args.sweep)
    t0 = time.perf_counter()
    with make_executor(args.executor, args.workers, args.scheduler) as executor:
        results = sweep.run(plan, executor)
    seconds = time.perf_counter() - t0
    meta = master_for(plan.system).metadata()
    texts, rows = {}, []
    for case, logs in zip(plan.cases, results):
        rec = _log_recording(logs, plan.log, meta, excited={"sweep": str(args.sweep), "case": case.name},
                             metadata={"system": str(plan.system.source), "parameters": case.parameters})
        texts.update(recording.recording_texts(args.out / f"{case.name}.csv", rec))
        rows.append({"case": case.name, "parameters": case.parameters,
                     "final": {k: float(rec[k][-1]) for k in rec.columns}})
    texts[args.out / "sweep.json"] = json.dumps({"sweep": str(args.sweep), "executor": args.executor,
                                                "runs": len(rows), "seconds": seconds, "cases": rows},
                                               indent=2) + "\n"
    args.out.mkdir(parents=True, exist_ok=True)
    recording.atomic_write_texts(texts)
    print(f"{len(rows)} runs in {seconds:.2f} s ({len(rows) / seconds:.1f} runs/s, {args.executor}) -> {args.out}")
    return 0


def _regress(args: argparse.Namespace) -> int:
    from harness import regress

    return regress.run_suite(args.suite, args.update, args.junit, args.plots)


def _ssp(args: argparse.Namespace) -> int:
    from harness import ssp

    print(ssp.export_ssp(args.system, args.out, args.drop_external_in_sums))
    return 0


def _report_fit(fit: object, args: argparse.Namespace, method: str) -> int:
    """Print a least-squares fit and, with ``--out``, write estimates, std and covariance as JSON."""
    import json

    from harness import recording

    print(fit.summary())
    if args.out:
        doc = {"method": method, "recording": str(args.recording), "parameters": fit.as_dict(),
               "std": dict(zip(fit.names, fit.std.tolist())), "names": fit.names,
               "covariance": fit.covariance.tolist(), "correlation_condition": fit.correlation_condition}
        recording.atomic_write_texts({args.out: json.dumps(doc, indent=2) + "\n"})
        print(args.out)
    return 0


def _joint_document(fit: object, method: str, source: Path) -> dict[str, object]:
    """The --out JSON of identify joint: SerialRobotJoint names (for writeback --values), regressor estimates beside."""
    from ident.joint import serial_joint_parameters

    names, estimate, covariance = serial_joint_parameters(fit)
    std = np.sqrt(np.diag(covariance))
    return {"method": method, "recording": str(source), "class": "MotionTwin.Plants.SerialRobotJoint",
            "parameters": dict(zip(names, estimate.tolist())), "std": dict(zip(names, std.tolist())),
            "names": names, "covariance": covariance.tolist(),
            "regressor_parameters": fit.as_dict(), "regressor_std": dict(zip(fit.names, fit.std.tolist())),
            "correlation_condition": fit.correlation_condition}


def _identify_joint_ml(args: argparse.Namespace) -> int:
    """identify joint --ml: maximum likelihood of the parameters and the cut-off (Abdellatif eq. 24);
    --cutoff is the start value and centre of the default search range."""
    import json

    from harness import recording
    from ident.ml import identify_joint_ml_recording

    if args.friction != "asymmetric":
        raise ValueError(f"--ml models asymmetric friction only (ident.ml), got --friction {args.friction!r}")
    if args.cutoff_range is not None and not 0 < args.cutoff_range[0] < args.cutoff_range[1]:
        raise ValueError(f"--cutoff-range LOW HIGH must satisfy 0 < LOW < HIGH [Hz], got {args.cutoff_range}")
    rec = recording.read_recording(args.recording, required=("time", args.position, args.force))
    result, notes = identify_joint_ml_recording(rec, args.f0, args.cutoff, cutoff_range=args.cutoff_range,
                                                position=args.position, force=args.force, min_speed=args.min_speed,
                                                nominal_inertia=args.nominal_inertia, source=str(args.recording))
    for note in notes:
        print(note)
    ml, (low, high) = result.ml, result.cutoff_range
    print(f"cut-off: start {args.cutoff:g} Hz, searched {low:g}..{high:g} Hz, ML estimate "
          f"{ml.cutoff_frequency:.6g} Hz")
    print(result.fit.summary())
    if args.out:
        doc = _joint_document(result.fit, "maximum likelihood with the filter cut-off as a parameter "
                                          "(Abdellatif eq. 24, CasADi/IPOPT)", args.recording)
        doc.update({"cutoff_frequency": ml.cutoff_frequency, "cutoff_start": args.cutoff,
                    "cutoff_range": [low, high], "negative_log_likelihood": ml.cost,
                    "start_regressor_parameters": result.start.fit.as_dict()})
        recording.atomic_write_texts({args.out: json.dumps(doc, indent=2) + "\n"})
        print(args.out)
    return 0


def _identify_joint(args: argparse.Namespace) -> int:
    import json

    from harness import recording
    from ident.joint import identify_joint_recording

    if args.ml:
        return _identify_joint_ml(args)
    if args.cutoff_range is not None:
        raise ValueError("--cutoff-range is the search interval of --ml: add --ml or drop it")
    rec = recording.read_recording(args.recording, required=("time", args.position, args.force))
    result, notes = identify_joint_recording(rec, args.f0, args.cutoff, position=args.position, force=args.force,
                                             min_speed=args.min_speed, friction=args.friction,
                                             nominal_inertia=args.nominal_inertia, source=str(args.recording))
    for note in notes:
        print(note)
    method = "inverse-dynamics Gauss-Markov least squares (Abdellatif, Bona eq. 2)"
    if not args.out:
        return _report_fit(result.fit, args, method)
    doc = _joint_document(result.fit, method, args.recording)
    print(result.fit.summary())
    recording.atomic_write_texts({args.out: json.dumps(doc, indent=2) + "\n"})
    print(args.out)
    return 0


def _identify_frf(args: argparse.Namespace) -> int:
    from ident.frf import cli_identify_frf

    return cli_identify_frf(args)


def _identify_oe(args: argparse.Namespace) -> int:
    from ident.outputerror import cli_identify_oe

    return cli_identify_oe(args)


def _identify_projection(args: argparse.Namespace) -> int:
    from ident.closedloop import cli_identify_projection

    return cli_identify_projection(args)


def _design_excitation(args: argparse.Namespace) -> int:
    from ident.excitation_design import cli_design_excitation

    return cli_design_excitation(args)


def _identify_hexapod(args: argparse.Namespace) -> int:
    from harness import recording
    from ident.hexapod import identify_hexapod_recording

    lengths = [f"L{i}" for i in range(1, 7)]
    forces = [f"tau{i}" for i in range(1, 7)]
    rec = recording.read_recording(args.recording, required=("time", *lengths, *forces))
    result, notes = identify_hexapod_recording(rec, args.f0, args.cutoff, min_leg_speed=args.min_speed,
                                               source=str(args.recording))
    for note in notes:
        print(note)
    return _report_fit(result.fit, args, "hexapod base parameters, Gauss-Markov least squares (Abdellatif)")


def _writeback(args: argparse.Namespace) -> int:
    import json

    import fmpy

    from fmus import writeback
    from harness.recording import atomic_write_texts

    values: dict[str, float] = {}
    provenance: dict[str, object] = {}
    if args.values:
        doc = json.loads(args.values.read_text())
        values = dict(doc.get("parameters", doc))
        provenance = {k: doc[k] for k in ("method", "recording", "names", "std", "covariance") if k in doc}
        provenance["values_file"] = str(args.values)
    for item in args.set:
        name, sep, value = item.partition("=")
        if not sep:
            raise ValueError(f"--set {item!r}: expected NAME=VALUE")
        values[name] = float(value)
    for item in args.rename:
        old, sep, new = item.partition("=")
        if not sep or old not in values:
            raise ValueError(f"--rename {item!r}: expected FROM=TO with FROM among {sorted(values)}")
        values[new] = values.pop(old)
    values = {k: v for k, v in values.items() if k not in args.drop}
    if not values:
        raise ValueError("nothing to write back: give --values FILE and/or --set NAME=VALUE")
    out = writeback.write_back(args.fmu, values, args.out, provenance)
    class_name = fmpy.read_model_description(str(out)).modelName
    modifier = args.modelica_out or args.out.with_suffix(".mo")
    atomic_write_texts({modifier: writeback.modelica_modifier(class_name, values, provenance),
                        args.out.with_suffix(".provenance.json"):
                            json.dumps({"fmu": str(out), "values": values, **provenance}, indent=2) + "\n"})
    print(out)
    print(modifier)
    return 0


def _tune(args: argparse.Namespace) -> int:
    from ident.tuning import cli_tune

    return cli_tune(args)


def _compare(args: argparse.Namespace) -> int:
    from harness.comparison import cli_compare

    return cli_compare(args)


def _diagnose(args: argparse.Namespace) -> int:
    from ident import diagnosis

    return diagnosis.run(str(args.bundle), str(args.out), args.quiet)


def _parser() -> argparse.ArgumentParser:
    from fmus.build import DEFAULT_OUT, FMI_VERSIONS, MODELICA_DIR

    parser = argparse.ArgumentParser(prog="motiontwin", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("build", help="build Modelica classes into FMI 2.0/3.0 FMUs (ME + CS, with sources)")
    p.add_argument("classes", nargs="*", help="full Modelica class names, e.g. MotionTwin.Plants.LinearMotorJoint")
    p.add_argument("--all", action="store_true", help="every class annotated __motiontwin(export=true)")
    p.add_argument("--modelica", type=Path, default=MODELICA_DIR, help="Modelica library folder or .mo file")
    p.add_argument("--fmi", nargs="+", choices=FMI_VERSIONS, default=list(FMI_VERSIONS), help="FMI versions")
    p.add_argument("--out", type=Path, default=DEFAULT_OUT, help="output folder (FMUs go to OUT/fmi2, OUT/fmi3)")
    p.set_defaults(func=_build)

    p = sub.add_parser("excite", help="sample an excitation experiment file into a recording")
    p.add_argument("experiment", type=Path, help="experiment TOML, e.g. harness/experiments/swept_sine_80_500.toml")
    p.add_argument("--out", type=Path, required=True, help="recording CSV (a JSON sidecar is written beside it)")
    p.add_argument("--mat", action="store_true", help="also write a MATLAB .mat file")
    p.set_defaults(func=_excite)

    p = sub.add_parser("run", help="co-simulate a system file and write a recording")
    p.add_argument("system", type=Path, help="system description (TOML)")
    p.add_argument("--input", action="append", default=[], metavar="NAME=EXPERIMENT.toml[:FIELD]",
                   help="drive external input NAME with an experiment's signal (FIELD: value, position, ...)")
    p.add_argument("--stop-time", type=float, default=None, help="[s] (default: the system file's stop_time)")
    p.add_argument("--log", default=None, help="log group to record (default: the first)")
    p.add_argument("--out", type=Path, required=True, help="recording CSV (a JSON sidecar is written beside it)")
    p.set_defaults(func=_run)

    p = sub.add_parser("sweep", help="run the cases of a sweep file (seeds, grids) through an executor")
    p.add_argument("sweep", type=Path, help="sweep file (TOML, see harness/sweep.py)")
    p.add_argument("--executor", default="inprocess", choices=["inprocess", "process", "dask"],
                   help="where the runs go (default inprocess); --scheduler implies dask")
    p.add_argument("--workers", type=int, default=None, help="worker processes (process pool, Dask LocalCluster)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="Dask scheduler, e.g. tcp://host:8786 (default: a LocalCluster on this machine)")
    p.add_argument("--out", type=Path, required=True, help="folder: one recording per case + sweep.json")
    p.set_defaults(func=_sweep)

    p = sub.add_parser("regress", help="run a regression suite against reference recordings (tolerance tubes)")
    p.add_argument("suite", type=Path, help="suite file (TOML)")
    p.add_argument("--update", action="store_true", help="rebaseline: rewrite the reference recordings")
    p.add_argument("--junit", type=Path, default=None, help="write JUnit XML here")
    p.add_argument("--plots", type=Path, default=None, help="write a plot per failing signal here")
    p.set_defaults(func=_regress)

    p = sub.add_parser("ssp", help="export a system file as an SSP archive")
    p.add_argument("system", type=Path)
    p.add_argument("out", type=Path)
    p.add_argument("--drop-external-in-sums", action="store_true",
                   help="drop external inputs from sum junctions (SSP 1.0 has no sum junctions)")
    p.set_defaults(func=_ssp)

    p = sub.add_parser("identify", help="identify plant parameters from a recording")
    kinds = p.add_subparsers(dest="kind", required=True)
    q = kinds.add_parser("joint", help="serial joint (inertia, gravity, friction) from a periodic recording by "
                                       "inverse-dynamics weighted least squares")
    q.add_argument("recording", type=Path, help="recording CSV (whole number of periods)")
    q.add_argument("--position", default="q", help="position column [rad or m] (default q)")
    q.add_argument("--force", default="u", help="force/torque column [N or N.m] (default u)")
    q.add_argument("--f0", type=float, required=True, help="fundamental frequency of the excitation [Hz]")
    q.add_argument("--cutoff", type=float, required=True, help="low-pass cut-off of the derivatives [Hz]")
    q.add_argument("--min-speed", type=float, default=0.0, help="drop samples slower than this (Coulomb sign)")
    q.add_argument("--friction", default="asymmetric", help="friction parametrisation (see ident.joint)")
    q.add_argument("--nominal-inertia", type=float, default=None,
                   help="a-priori J [kg.m2 or kg]: refuse a fit more than 10x away (mis-declared units)")
    q.add_argument("--ml", action="store_true",
                   help="maximum likelihood with the cut-off as a parameter (Abdellatif eq. 24); --cutoff starts it")
    q.add_argument("--cutoff-range", type=float, nargs=2, default=None, metavar=("LOW", "HIGH"),
                   help="with --ml: cut-off search interval [Hz] (default cutoff/2 .. 2 cutoff)")
    q.add_argument("--out", type=Path, default=None,
                   help="JSON in the SerialRobotJoint FMU's parameter names (M, k, q_off, beta_*) for "
                        "writeback --values; the regressor estimates beside them")
    q.set_defaults(func=_identify_joint)
    q = kinds.add_parser("frf", help="joint model K/(s(s+alpha)) x resonance/antiresonance pairs (Cheung eqs. 6-8) "
                                     "from a swept-sine recording")
    q.add_argument("recording", type=Path, nargs="+",
                   help="recording CSV with the force and the encoder position (several with --worst-case)")
    q.add_argument("--worst-case", action="store_true",
                   help="fit each recording (one per actuator position) and use the lowest-gain model (Cheung)")
    q.add_argument("--input", default="u", help="force column [N] (default u)")
    q.add_argument("--position", default="q", help="position column [m] (default q)")
    q.add_argument("--segment", type=int, default=None,
                   help="Welch segment length [samples] (default: largest power of two <= min(4096, n/4))")
    q.add_argument("--min-coherence", type=float, default=0.9, help="use FRF points above this coherence")
    q.add_argument("--low-frequency", type=Path, default=None, metavar="MOVE.csv",
                   help="point-to-point recording (same columns): alpha from the PEM fit of K/(s(s+alpha)) (Cheung)")
    q.add_argument("--alpha", type=float, default=None,
                   help="hold alpha [1/s] at this value (default: fitted if the sweep band determines it, else 10)")
    q.add_argument("--out", type=Path, default=None, help="JSON in the CheungJoint FMU's parameter names")
    q.set_defaults(func=_identify_frf)
    q = kinds.add_parser("oe", help="output-error refit of any Modelica plant's parameters (CasADi free run of the "
                                    "equations the FMU is built from; closed loop with --controller)")
    q.add_argument("recording", type=Path, help="recording CSV, uniformly sampled")
    q.add_argument("--modelica", type=Path, default=MODELICA_DIR, help="Modelica library folder or .mo file")
    q.add_argument("--class", dest="class_name", required=True,
                   help="plant class, e.g. MotionTwin.Plants.LinearMotorJoint")
    q.add_argument("--free", required=True, help="comma-separated parameters to fit, e.g. m,d")
    q.add_argument("--input", default="u", help="plant input = recording column (default u)")
    q.add_argument("--output", default="q", help="plant output/state = recording column (default q)")
    q.add_argument("--controller", type=Path, default=None,
                   help="controller JSON (discrete_state_space, or an experiment.json); the recording then needs r")
    q.add_argument("--max-nfev", type=int, default=50, help="residual evaluations per fit (single shooting)")
    q.add_argument("--shooting", choices=("single", "multiple"), default="single",
                   help="single shooting (Gauss-Newton, default) or multiple shooting (IPOPT, continuity constraints)")
    q.add_argument("--segments", type=int, default=4, help="segments of the recording for --shooting multiple")
    q.add_argument("--out", type=Path, default=None, help="JSON for writeback --values")
    q.set_defaults(func=_identify_oe)

    q = kinds.add_parser("hexapod", help="hexapod base parameters from a periodic recording of leg lengths "
                                         "L1..L6 [m] and leg forces tau1..tau6 [N]")
    q.add_argument("recording", type=Path, help="recording CSV (whole number of periods)")
    q.add_argument("--f0", type=float, required=True, help="fundamental frequency of the excitation [Hz]")
    q.add_argument("--cutoff", type=float, required=True, help="low-pass cut-off of the derivatives [Hz]")
    q.add_argument("--min-speed", type=float, default=0.0, help="drop samples where a leg is slower [m/s]")
    q.add_argument("--out", type=Path, default=None, help="write estimates, std and covariance as JSON")
    q.set_defaults(func=_identify_hexapod)

    q = kinds.add_parser("projection", help="closed-loop plant y = B/F u by the projection method (Bona eqs. "
                                            "10-12), printed beside the naive output-error fit")
    q.add_argument("recording", type=Path, help="recording CSV, uniformly sampled, of a closed-loop experiment")
    q.add_argument("--reference", default="r", help="reference column the loop is driven by (default r)")
    q.add_argument("--input", default="u", help="plant input column (default u)")
    q.add_argument("--output", default="q", help="plant output column (default q)")
    q.add_argument("--nb", type=int, default=2, help="numerator coefficients of B (default 2)")
    q.add_argument("--nf", type=int, default=2, help="denominator order of F (default 2)")
    q.add_argument("--delay", type=int, default=1, help="input delay of B [samples] (default 1)")
    q.add_argument("--noncausal", type=int, default=0, help="FIR taps on future reference samples, M1 (default 0)")
    q.add_argument("--causal", type=int, default=100, help="FIR taps on past reference samples, M2 (default 100)")
    q.add_argument("--periodic", action="store_true", help="the recording holds whole periods: shifts wrap around")
    q.add_argument("--skip", type=int, default=None, help="initial samples left out of the fits (default --causal)")
    q.add_argument("--out", type=Path, default=None, help="JSON with both models (B, F, gain, modes)")
    q.set_defaults(func=_identify_projection)

    p = sub.add_parser("design-excitation", help="optimal periodic Fourier excitation (condition number or "
                                                 "D-optimality) -> experiment file for excite")
    designs = p.add_subparsers(dest="plant", required=True)
    q = designs.add_parser("joint", help="serial joint (inertia, gravity, asymmetric friction), CasADi/IPOPT")
    q.add_argument("--criterion", choices=("cond", "dopt"), default="dopt",
                   help="cond: regressor condition number (eq. 21); dopt: D-optimality, log det (eq. 22)")
    q.add_argument("--f0", type=float, required=True, help="fundamental frequency [Hz]")
    q.add_argument("--harmonics", type=int, required=True, help="number of harmonics")
    q.add_argument("--q-center", type=float, default=0.0, help="centre of the position range [rad or m]")
    q.add_argument("--q-range", type=float, required=True, help="position within q-center +- this [rad or m]")
    q.add_argument("--v-max", type=float, required=True, help="speed limit [rad/s or m/s]")
    q.add_argument("--a-max", type=float, required=True, help="acceleration limit [rad/s2 or m/s2]")
    q.add_argument("--sample-time", type=float, default=1e-3, help="experiment sample time [s] (default 1e-3)")
    q.add_argument("--periods", type=int, default=10, help="periods in the experiment (default 10)")
    q.add_argument("--starts", type=int, default=3, help="random IPOPT starts, the best is kept (default 3)")
    q.add_argument("--seed", type=int, default=0)
    q.add_argument("--design-samples", type=int, default=100, help="instants per period the limits hold at")
    q.add_argument("--name", default=None, help="experiment name (default: the file stem)")
    q.add_argument("--target", default=None, help="port the experiment drives, e.g. r")
    q.add_argument("--out", type=Path, required=True, help="experiment TOML (kind fourier) for motiontwin excite")
    q.set_defaults(func=_design_excitation)

    p = sub.add_parser("writeback", help="write fitted values into a new FMU's start values (rebuilt binary)")
    p.add_argument("fmu", type=Path, help="an FMU built by motiontwin (it carries its sources)")
    p.add_argument("--out", type=Path, required=True, help="the new FMU (never the original)")
    p.add_argument("--values", type=Path, default=None, help="JSON: {\"parameters\": {...}} as identify writes")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="a value to write")
    p.add_argument("--rename", action="append", default=[], metavar="FROM=TO",
                   help="map an identified parameter name to the FMU's variable name")
    p.add_argument("--drop", action="append", default=[], metavar="NAME", help="leave this value out")
    p.add_argument("--modelica-out", type=Path, default=None,
                   help="Modelica modifier file (default: OUT with suffix .mo)")
    p.set_defaults(func=_writeback)

    p = sub.add_parser("tune", help="tune the robust joint controller (Cheung eqs. 9-18) on the discrete loop")
    p.add_argument("--plant", action="append", default=[],
                   metavar="K=..,alpha=..,omega=..,zeta=..,omega_bar=..,zeta_bar=..",
                   help="one actuator position (repeat); missing fields from MotionTwin.Plants.CheungJoint [SI, rad/s]")
    p.add_argument("--plant-fmu", type=Path, default=None,
                   help="plant FMU (Model Exchange) linearised per --plant (then NAME=VALUE start values of the FMU)")
    p.add_argument("--plant-input", default="u", help="plant FMU input (default u)")
    p.add_argument("--plant-output", default="q", help="plant FMU output (default q)")
    p.add_argument("--gain-spread", type=float, default=0.3, help="with one --plant: K*(1 -/+ spread) sets")
    p.add_argument("--resonance-spread", type=float, default=0.1, help="with one --plant: resonances *(1 +/- spread)")
    p.add_argument("--ts", type=float, default=5e-4, help="sample period [s] (default 5e-4, 2 kHz)")
    p.add_argument("--delay", type=int, default=1, help="computation delay [samples] (default 1)")
    p.add_argument("--tau", type=float, default=None, help="derivative filter time constant [s] (default 2 Ts)")
    p.add_argument("--gm", type=float, default=7.0, help="GM lower bound [dB] (eq. 14)")
    p.add_argument("--pm-min", type=float, default=45.0, help="PM band lower end [deg] (eq. 15 read as a band)")
    p.add_argument("--pm-max", type=float, default=60.0, help="PM band upper end [deg] (eq. 15: PM <= 60)")
    p.add_argument("--ms", type=float, default=2.0, help="upper bound on max|S| (modulus margin 1/Ms)")
    p.add_argument("--s-below-bw", type=float, default=None, help="upper bound on max|S| below CLBW (eq. 17)")
    p.add_argument("--bw-min", type=float, default=None, help="lower bound on the worst-case CLBW [Hz] (eq. 16)")
    p.add_argument("--tau-max", type=float, default=0.03,
                   help="upper bound on the slowest closed-loop time constant [s] on every plant set (inf: unconstrained)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--popsize", type=int, default=12, help="differential evolution population multiplier")
    p.add_argument("--maxiter", type=int, default=80, help="differential evolution generations")
    p.add_argument("--refine", type=int, default=3, help="Nelder-Mead then SLSQP (gradient) refinements from the best members")
    p.add_argument("--compare-table2", action="store_true", help="print Cheung Table 2 designs beside the tuned one")
    p.add_argument("--out", type=Path, default=None, help="JSON with parameters, spec, margins (writeback reads it)")
    p.add_argument("--fmu", type=Path, default=None, help="controller FMU to write into (default: build one)")
    p.add_argument("--fmi", choices=("2.0", "3.0"), default="3.0", help="FMI version of the built controller FMU")
    p.add_argument("--fmu-out", type=Path, default=None, help="new controller FMU with the tuned start values")
    p.add_argument("--plots", type=Path, default=None,
                   help="folder for Bode/Nyquist/sensitivity PNGs (tuning_joint.png or tuning_manipulator_d1..d7.png)")
    p.add_argument("--manipulator", action="store_true",
                   help="per-actuator design on the CheungManipulator FMU linearised at --poses poses "
                        "(--plant: eq. (8) flexible mode; --plant-fmu: a manipulator FMU)")
    p.add_argument("--poses", type=int, default=5, help="with --manipulator: poses along the workspace segment")
    p.add_argument("--rigid", action="store_true", help="with --manipulator: no eq. (8) flexible mode on the channels")
    p.add_argument("--no-feedforward", action="store_true", help="keep Kv, Ka, Kj at the FMU defaults")
    p.add_argument("--no-jerk", action="store_true", help="fit Kv, Ka only (Kj = 0)")
    p.set_defaults(func=_tune)

    p = sub.add_parser("compare", help="Cheung & Hung's point-to-point comparison on the coupled 4-DOF plant: "
                                       "robust controller vs computed-torque PID, Tables 3/4, Figs. 4-7")
    p.add_argument("--out", type=Path, required=True, help="output folder (recordings, table.txt/json, figures)")
    p.add_argument("--design", action="append", default=[], type=Path, metavar="JSON",
                   help="robust design from 'motiontwin tune --out' (once for all joints, or 4 times: d1 d3 d5 d7)")
    p.add_argument("--stop-time", type=float, default=0.25, help="[s] run length (default 0.25)")
    p.add_argument("--ct-pole-hz", type=float, default=20.0, help="computed-torque triple pole [Hz] (default 20)")
    p.add_argument("--table2-reading", choices=("per-sample", "continuous"), default="per-sample",
                   help="how Table 2's Kp, Ki, Kd are read (default per-sample: Ki/Ts, Kd*Ts)")
    p.add_argument("--fmu-dir", type=Path, default=None, help="where to build the FMUs (default: OUT/fmus)")
    p.set_defaults(func=_compare)

    p = sub.add_parser("diagnose", help="locate and name the physics a recording shows and the model lacks; "
                                        "refit, rebuild the FMU, validate")
    p.add_argument("bundle", type=Path, help="bundle folder with experiment.json, plant .mo, train/validation CSV")
    p.add_argument("--out", type=Path, required=True, help="output folder (diagnosis.json, report.md, FMU, ...)")
    p.add_argument("--quiet", action="store_true", help="do not print progress")
    p.set_defaults(func=_diagnose)

    p = sub.add_parser("demo", help="build the example FMUs and run the example end to end")
    p.add_argument("--out", type=Path, default=Path("build") / "demo")
    p.set_defaults(func=_demo)
    return parser


def main(argv: list[str] | None = None) -> int:
    from fmus.frontend import ModelicaError
    from fmus.package import BuildError
    from harness.fmu_instance import FMUCallError

    args = _parser().parse_args(argv)
    func: Callable[[argparse.Namespace], int] = args.func
    try:
        return func(args)
    except (ModelicaError, BuildError, FMUCallError, KeyError, ValueError, FileNotFoundError) as exc:
        print(f"motiontwin {args.command}: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
