"""``motiontwin identify / design-excitation``: identification from recordings and excitation design."""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def _report_fit(fit: object, args: argparse.Namespace, method: str) -> int:
    """Print a least-squares fit and, with ``--out``, write estimates, std and covariance as JSON."""
    import json

    from motiontwin.harness import recording

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
    from motiontwin.ident.joint import serial_joint_parameters

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

    from motiontwin.harness import recording
    from motiontwin.ident.ml import identify_joint_ml_recording

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

    from motiontwin.harness import recording
    from motiontwin.ident.joint import identify_joint_recording

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
    from motiontwin.ident.frf import cli_identify_frf

    return cli_identify_frf(args)


def _identify_oe(args: argparse.Namespace) -> int:
    from motiontwin.ident import startvalues
    from motiontwin.ident.outputerror import cli_identify_oe

    args.start_values = {**(startvalues.read_values_file(args.values) if args.values else {}),
                         **startvalues.parse_assignments(args.set)}

    return cli_identify_oe(args)


def _identify_projection(args: argparse.Namespace) -> int:
    from motiontwin.ident.closedloop import cli_identify_projection

    return cli_identify_projection(args)


def _identify_hexapod(args: argparse.Namespace) -> int:
    from motiontwin.harness import recording
    from motiontwin.ident.hexapod import identify_hexapod_recording

    lengths = [f"L{i}" for i in range(1, 7)]
    forces = [f"tau{i}" for i in range(1, 7)]
    rec = recording.read_recording(args.recording, required=("time", *lengths, *forces))
    result, notes = identify_hexapod_recording(rec, args.f0, args.cutoff, min_leg_speed=args.min_speed,
                                               source=str(args.recording))
    for note in notes:
        print(note)
    return _report_fit(result.fit, args, "hexapod base parameters, Gauss-Markov least squares (Abdellatif)")


def _design_excitation(args: argparse.Namespace) -> int:
    from motiontwin.ident.excitation_design import cli_design_excitation

    return cli_design_excitation(args)


def register(sub: argparse._SubParsersAction) -> None:
    """Add this module's subcommands to the ``motiontwin`` parser."""
    from motiontwin.fmus.build import MODELICA_DIR

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
    q.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="start value of a plant parameter (repeatable; over --values and the Modelica default)")
    q.add_argument("--values", type=Path, default=None, metavar="FILE",
                   help="start values as JSON, {\"parameters\": {NAME: VALUE}} (as identify --out writes) or flat")
    q.add_argument("--no-auto-start", dest="auto_start", action="store_false",
                   help="do not start the free parameters from inverse-dynamics least squares (default: those "
                        "entering the plant's force linearly, e.g. m, d, Fc, without --set/--values, do)")
    q.add_argument("--initial", choices=("samples", "rest"), default="samples",
                   help="initial velocity: from the first samples (default; a loop moving at t = 0) or at rest")
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
