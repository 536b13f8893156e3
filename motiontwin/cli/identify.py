"""``motiontwin identify / design-excitation``: identification from recordings and excitation design."""
from __future__ import annotations

import argparse
from pathlib import Path

from motiontwin.cli.arguments import name_values


def _report_fit(fit: object, args: argparse.Namespace, method: str) -> int:
    """Print a least-squares fit and, with ``--out``, write estimates, std and covariance as JSON."""
    import json

    from motiontwin.harness import recording

    print(fit.summary())
    if args.out:
        doc = {"method": method, "recording": str(args.recording), "parameters": fit.as_dict(),
               "std": dict(zip(fit.names, fit.std.tolist())), "names": fit.names,
               "std_hac": dict(zip(fit.names, fit.robust_std.tolist())), "hac_lags": fit.robust_lags,
               "covariance": fit.covariance.tolist(), "correlation_condition": fit.correlation_condition}
        recording.atomic_write_texts({args.out: json.dumps(doc, indent=2) + "\n"})
        print(args.out)
    return 0


def _joint_document(fit: object, method: str, source: Path) -> dict[str, object]:
    """The --out JSON of identify joint: SerialRobotJoint names (for writeback --values) for a revolute fit, the
    names of MotionTwin.Effects.JointBase-style axes (m, d, Fc, F0) for a prismatic one; regressor estimates beside."""
    import dataclasses

    import numpy as np

    from motiontwin.ident.joint import prismatic_axis_parameters, serial_joint_parameters

    convert = serial_joint_parameters if "g_sin" in fit.names else prismatic_axis_parameters
    plant = "MotionTwin.Plants.SerialRobotJoint" if "g_sin" in fit.names else "MotionTwin.Plants.PrismaticAxis"
    names, estimate, covariance = convert(fit)
    std = np.sqrt(np.diag(covariance))
    doc = {"method": method, "recording": str(source), "class": plant,
           "parameters": dict(zip(names, estimate.tolist())), "std": dict(zip(names, std.tolist())),
           "names": names, "covariance": covariance.tolist(),
           "regressor_parameters": fit.as_dict(), "regressor_std": dict(zip(fit.names, fit.std.tolist())),
           "correlation_condition": fit.correlation_condition}
    if fit.robust_covariance is not None:
        robust = convert(dataclasses.replace(fit, covariance=fit.robust_covariance))[2]
        doc.update({"std_hac": dict(zip(names, np.sqrt(np.diag(robust)).tolist())), "hac_lags": fit.robust_lags,
                    "regressor_std_hac": dict(zip(fit.names, fit.robust_std.tolist()))})
    return doc


def _identify_joint_ml(args: argparse.Namespace) -> int:
    """identify joint --ml: maximum likelihood of the parameters and the cut-off (Abdellatif eq. 24);
    --cutoff is the start value and centre of the default search range."""
    import json

    from motiontwin.harness import recording
    from motiontwin.ident.maximum_likelihood import identify_joint_ml_recording

    if args.friction not in ("auto", "asymmetric") or args.gravity not in ("auto", "sine"):
        raise ValueError(f"--ml models the revolute joint with asymmetric friction and sine gravity only (ident.maximum_likelihood), "
                         f"got --friction {args.friction!r} --gravity {args.gravity!r}")
    if args.cutoff_range is not None and not 0 < args.cutoff_range[0] < args.cutoff_range[1]:
        raise ValueError(f"--cutoff-range LOW HIGH must satisfy 0 < LOW < HIGH [Hz], got {args.cutoff_range}")
    rec = recording.read_recording(args.recording, required=("time", args.position, args.force))
    result, notes = identify_joint_ml_recording(rec, args.f0, args.cutoff, cutoff_range=args.cutoff_range,
                                                position=args.position, force=args.force, min_speed=args.min_speed,
                                                nominal_inertia=args.nominal_inertia, source=str(args.recording))
    for note in [*notes, *result.start.record_notes]:
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
                                             min_speed=args.min_speed, friction=args.friction, gravity=args.gravity,
                                             nominal_inertia=args.nominal_inertia, source=str(args.recording))
    for note in [*notes, *result.record_notes]:
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
    """``identify frf REC [REC ...]``: prints unit conversions, where alpha comes from, the fitted band, the
    parameters (with --worst-case the per-position table) and writes ``frf_document`` to --out."""
    import json

    from motiontwin.harness import recording
    from motiontwin.ident.frf import frf_document, identify_frf_recording, identify_frf_worst_case

    paths = list(args.recording)
    if len(paths) > 1 and not args.worst_case:
        raise ValueError(f"{len(paths)} recordings given: pass --worst-case to fit each and select the lowest gain")
    columns = ("time", args.input, args.position)
    options = dict(input=args.input, position=args.position, segment_length=args.segment,
                   min_coherence=args.min_coherence, alpha=args.alpha)
    if args.low_frequency is not None:
        options.update(low_frequency=recording.read_recording(args.low_frequency, required=columns),
                       low_frequency_source=str(args.low_frequency))
    recs = [recording.read_recording(p, required=columns) for p in paths]
    if args.worst_case:
        result, notes = identify_frf_worst_case(recs, [str(p) for p in paths], **options)
        selected = result.fits[result.selected]
    else:
        result, notes = identify_frf_recording(recs[0], source=str(paths[0]), **options)
        selected = result
    for note in notes:
        print(note)
    data = selected.data
    print(f"fitted band {data.frequency[0]:.4g}-{data.frequency[-1]:.4g} Hz ({data.frequency.size} FRF points)")
    if args.worst_case:
        print(result.table())
    doc = frf_document(result, str(paths[0]))
    if notes:
        doc["notes"] = notes
    for name, value in doc["parameters"].items():
        print(f"{name:>12} {value:13.6g}")
    print(f"rms log-magnitude error {selected.rms_log_error:.3g}")
    if args.out:
        recording.atomic_write_texts({args.out: json.dumps(doc, indent=2) + "\n"})
        print(args.out)
    return 0


def _identify_oe(args: argparse.Namespace) -> int:
    """``identify oe``: refit, print the table and, with --out, write the JSON that ``writeback --values``
    reads ({"parameters", "std", "covariance", ...})."""
    import json

    import numpy as np

    from motiontwin.fmus import build
    from motiontwin.harness.recording import atomic_write_texts, read_recording
    from motiontwin.cli.arguments import loop_controller
    from motiontwin.ident import observer as observer_module
    from motiontwin.ident import startvalues, validation
    from motiontwin.ident.outputerror import identify

    known = args.controller is not None and args.controller != "unknown"
    rec = read_recording(args.recording, [args.output, args.input] + (["r"] if known else []))
    controller, signals, observer = loop_controller(args.controller, rec, args.output, args.input)
    model = build.load_model(args.class_name, args.modelica)
    free = [n.strip() for n in args.free.split(",") if n.strip()]
    start = {**(startvalues.read_values_file(args.values) if args.values else {}),
             **{name: value for item in args.set for name, value in name_values(item, "--set").items()}}
    startvalues.check_parameters(model, start, "--set/--values")

    def refit(loop: object) -> object:
        """The output-error refit in the closed loop of ``loop`` (a controller, an observer's, or None)."""
        return identify(model, rec, free, loop, signals, max_nfev=args.max_nfev, shooting=args.shooting,
                        segments=args.segments, start=start, auto_start=args.auto_start, initial=args.initial)

    result = refit(controller)
    if observer is not None:
        # the observer fitted with the refitted plant (as the diagnosis fits it), then the plant again
        values = {v.name: float(v.start) for v in model.parameters} | result.fit.values
        driven = signals.input if signals.input in [v.name for v in model.inputs] else None
        fitted = observer_module.fitted_with_plant(observer, model, values, rec, signals.output, driven, signals)
        if (fitted.bandwidth_hz, fitted.mass) != (observer.bandwidth_hz, observer.mass):
            controller = fitted.controller()
            result = refit(controller)
        observer = fitted
        print(observer.describe())
    stats = result.statistics
    print(stats.summary())
    multiple = args.shooting == "multiple"
    how = f"multiple shooting, {args.segments} segments" if multiple else "single shooting"
    scored = validation.free_run(model, result.fit.values, rec, controller=controller, signals=signals,
                                 initial=args.initial)
    print(f"RMS output error {scored.rms_q:.4g} {rec.units.get(signals.output, '')} "
          f"({validation.RMS_DEFINITION}; validate of --out on this recording prints the same); "
          f"{'predictor' if observer else 'closed' if controller else 'open'} loop, {result.loop.substeps} RK4 "
          f"substeps per sample, {how}")
    if args.out:
        solver = f"multiple shooting ({args.segments} segments, IPOPT, " if multiple else "single shooting ("
        method = (f"output-error refit, CasADi {solver}RK4, AD Jacobian), "
                  f"{'prediction-error predictor' if observer else 'closed loop' if controller else 'open loop'}")

        def number(v: float) -> float | None:
            return float(v) if np.isfinite(v) else None

        doc = {"method": method, "recording": str(args.recording), "modelica": str(args.modelica),
               "class": args.class_name, "parameters": stats.as_dict(),
               "fixed_parameters": {k: v for k, v in result.fit.values.items() if k not in stats.names},
               "initial": args.initial, "std": {n: number(v) for n, v in zip(stats.names, stats.std)},
               "names": stats.names, "at_bound": stats.at_bound,
               "std_hac": {n: number(v) for n, v in zip(stats.names, stats.robust_std)},
               "hac_lags": stats.robust_lags,
               "covariance": stats.covariance.tolist(), "correlation_condition": stats.correlation_condition,
               "rms_output_error": scored.rms_q, "rms_definition": validation.RMS_DEFINITION,
               "converged": result.fit.success, "controller": observer.as_dict() if observer else None}
        atomic_write_texts({args.out: json.dumps(doc, indent=2) + "\n"})
        print(args.out)
    return 0


def _identify_projection(args: argparse.Namespace) -> int:
    """``identify projection``: the projection-method estimate printed next to the naive output-error one,
    both written to --out as JSON."""
    import json

    from motiontwin.harness import recording
    from motiontwin.ident.closedloop import identify_projection_recording, model_features

    for flag, value, least in (("--nb", args.nb, 1), ("--nf", args.nf, 1), ("--delay", args.delay, 0),
                               ("--noncausal", args.noncausal, 0), ("--causal", args.causal, 0),
                               ("--skip", args.skip, 0)):
        if value is not None and value < least:
            raise ValueError(f"{flag} must be >= {least}, got {value}")
    rec = recording.read_recording(args.recording, required=("time", args.reference, args.input, args.output))
    skip = args.causal if args.skip is None else args.skip
    result, fs = identify_projection_recording(rec, args.reference, args.input, args.output, args.nb, args.nf,
                                               delay=args.delay, n_noncausal=args.noncausal, n_causal=args.causal,
                                               periodic=args.periodic, skip=skip, source=str(args.recording))
    projected, naive = (model_features(m, fs) for m in (result.projection_model, result.naive_model))
    print(f"projection of {args.input!r} on {args.reference!r}: lags -{args.noncausal}..{args.causal}, "
          f"corr(u_hat, u - u_hat) = {result.projection.correlation:.2e}")
    print(f"{'':>16} {'projection':>14} {'naive OE':>14}")
    rows = [("static gain", projected["static_gain"], naive["static_gain"])]
    for k, (mp, mn) in enumerate(zip(projected["modes"], naive["modes"]), start=1):
        rows += [(f"mode {k} f [Hz]", mp["frequency_hz"], mn["frequency_hz"]),
                 (f"mode {k} damping", mp["damping"], mn["damping"])]
    rows += [(f"b{i}", bp, bn) for i, (bp, bn) in enumerate(zip(projected["b"], naive["b"]))]
    rows += [(f"f{i}", fp, fn) for i, (fp, fn) in enumerate(zip(projected["f"], naive["f"])) if i > 0]
    rows.append(("rms error", projected["rms_error"], naive["rms_error"]))
    for name, a, b in rows:
        print(f"{name:>16} {a:14.6g} {b:14.6g}")
    if args.out:
        doc = {"method": "projection method, output-error model y = B/F u_hat (Bona eqs. 10-12)",
               "recording": str(args.recording), "columns": {"reference": args.reference, "input": args.input,
                                                             "output": args.output},
               "sample_rate": fs, "orders": {"nb": args.nb, "nf": args.nf, "delay": args.delay, "skip": skip},
               "projection": {"n_noncausal": args.noncausal, "n_causal": args.causal, "periodic": args.periodic,
                              "correlation": result.projection.correlation},
               "projection_model": projected, "naive_model": naive}
        recording.atomic_write_texts({args.out: json.dumps(doc, indent=2) + "\n"})
        print(args.out)
    return 0


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


EXCITATION_CRITERIA = {"cond": "condition", "dopt": "d_optimal"}


def _design_excitation(args: argparse.Namespace) -> int:
    """``design-excitation joint``: designs the joint's Fourier coefficients, prints its exact criteria beside
    the median of 20 random designs under the same limits, and writes a ``fourier`` experiment file
    (harness.excitation) that ``motiontwin excite`` samples."""
    import numpy as np

    from motiontwin.harness.excitation import periodic_time_grid
    from motiontwin.harness.experiment import fourier_experiment_text
    from motiontwin.harness.recording import atomic_write_texts
    from motiontwin.harness.system import check_run_length
    from motiontwin.ident.excitation_design import (ExcitationLimits, evaluate_design, optimize_excitation,
                                                    random_design)

    for flag, value in (("--f0", args.f0), ("--q-range", args.q_range), ("--v-max", args.v_max),
                        ("--a-max", args.a_max), ("--sample-time", args.sample_time)):
        if not value > 0:
            raise ValueError(f"{flag} must be > 0, got {value}")
    for flag, value in (("--harmonics", args.harmonics), ("--periods", args.periods), ("--starts", args.starts)):
        if value < 1:
            raise ValueError(f"{flag} must be >= 1, got {value}")
    if args.periods < 2:
        raise ValueError(f"--periods must be >= 2 (identification averages periods), got {args.periods}")
    check_run_length(0.0, args.periods / args.f0, args.sample_time, f"--periods / --f0 ({args.periods} periods)")
    try:
        n_per = periodic_time_grid(1.0 / args.f0, 1, args.sample_time).size
    except ValueError as exc:
        raise ValueError(f"--sample-time {args.sample_time} with --f0 {args.f0}: {exc}") from None
    if args.harmonics * args.f0 >= 0.5 / args.sample_time:
        raise ValueError(f"--harmonics {args.harmonics} x --f0 {args.f0} Hz reaches the Nyquist frequency of "
                         f"--sample-time {args.sample_time} s")
    limits = ExcitationLimits(args.q_center, args.q_range, args.v_max, args.a_max)
    criterion = EXCITATION_CRITERIA[args.criterion]
    try:
        design = optimize_excitation(limits, args.f0, args.harmonics, criterion=criterion,
                                     n_samples=args.design_samples, n_starts=args.starts, seed=args.seed)
    except RuntimeError as exc:
        raise ValueError(f"{exc}; widen --q-range/--v-max/--a-max or try more --starts") from None
    n_eval = max(n_per, 2000)
    metrics = evaluate_design(design, limits, n_samples=n_eval)
    rng = np.random.default_rng(args.seed)
    randoms = [evaluate_design(random_design(limits, args.f0, args.harmonics, rng), limits, n_samples=n_eval)
               for _ in range(20)]
    print(f"{criterion} design, {args.harmonics} harmonics of {args.f0:g} Hz")
    print(f"{'':>22} {'design':>12} {'random (median of 20)':>22}")
    print(f"{'cond(regressor)':>22} {metrics.condition_number:12.4g} "
          f"{np.median([r.condition_number for r in randoms]):22.4g}")
    print(f"{'log det information':>22} {metrics.log_det_information:12.4g} "
          f"{np.median([r.log_det_information for r in randoms]):22.4g}")
    print(f"{'largest limit use':>22} {metrics.max_constraint_ratio:12.4g}")
    comments = [f"Optimal Fourier excitation of a serial joint (ident/excitation_design.py), criterion {criterion}.",
                f"Limits: q in {args.q_center:g} +- {args.q_range:g}, |qd| <= {args.v_max:g}, "
                f"|qdd| <= {args.a_max:g} (rad or m, per s, per s^2).",
                f"cond(regressor) = {metrics.condition_number:.6g}, log det information = "
                f"{metrics.log_det_information:.6g}, largest limit use = {metrics.max_constraint_ratio:.4f}.",
                "a, b are velocity amplitudes; duration = n_periods / f_fundamental."]
    text = fourier_experiment_text(args.name or args.out.stem, args.sample_time, args.f0, args.periods,
                                   design.a, design.b, design.q0, target=args.target, comments=comments,
                                   description=f"{criterion} design, {args.harmonics} harmonics of {args.f0:g} Hz, "
                                               f"{args.periods} periods", source=args.out)
    atomic_write_texts({args.out: text})
    print(args.out)
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add this module's subcommands to the ``motiontwin`` parser."""
    from motiontwin.fmus import MODELICA_DIR

    p = sub.add_parser("identify", help="identify plant parameters from a recording")
    kinds = p.add_subparsers(dest="kind", required=True)
    q = kinds.add_parser("joint", help="serial joint or prismatic axis (inertia, gravity or constant force, "
                                       "friction) from a periodic recording by inverse-dynamics weighted least squares",
                         description="Inverse-dynamics Gauss-Markov least squares on the period-averaged, "
                                     "frequency-domain filtered recording (ident.joint). The sample time is the "
                                     "sidecar's (else the median step, snapped to its clock when within the jitter); "
                                     "time-stamp jitter up to 1e-3 of it is "
                                     "accepted and reported; samples after the last whole period are dropped and "
                                     "reported.")
    q.add_argument("recording", type=Path, help="recording CSV (at least 2 periods; the rest is trimmed)")
    q.add_argument("--position", default="q", help="position column [rad or m] (default q)")
    q.add_argument("--force", default="u", help="force/torque column [N or N.m] (default u)")
    q.add_argument("--f0", type=float, default=None,
                   help="fundamental frequency of the excitation [Hz]; default: found in the spectrum of the "
                        "reference column r (else of the position) as a whole number of samples per period, printed")
    q.add_argument("--cutoff", type=float, required=True, help="low-pass cut-off of the derivatives [Hz]")
    q.add_argument("--min-speed", type=float, default=0.0,
                   help="drop samples slower than this [m/s or rad/s] (sign of Coulomb unreliable there)")
    q.add_argument("--friction", default="auto", choices=("auto", "asymmetric", "symmetric", "viscous", "none"),
                   help="asymmetric: fv_pos*v + fc_pos for v > 0, fv_neg*v - fc_neg for v < 0 (Bona eq. 2); "
                        "symmetric: fv*v + fc*sign(v); viscous: fv*v; none. auto (default): asymmetric on a "
                        "rotary axis, symmetric on a linear one")
    q.add_argument("--gravity", default="auto", choices=("auto", "sine", "constant", "none"),
                   help="sine: k*sin(q + q_off) of a revolute joint; constant: a constant force F0 (weight of an "
                        "inclined axis, preload, offset); none. auto (default): sine on a rotary axis (rad), "
                        "constant on a linear one (m)")
    q.add_argument("--nominal-inertia", type=float, default=None,
                   help="a-priori J [kg.m2 or kg]: refuse a fit more than 10x away (mis-declared units)")
    q.add_argument("--ml", action="store_true",
                   help="maximum likelihood with the cut-off as a parameter (Abdellatif eq. 24); --cutoff starts it")
    q.add_argument("--cutoff-range", type=float, nargs=2, default=None, metavar=("LOW", "HIGH"),
                   help="with --ml: cut-off search interval [Hz] (default cutoff/2 .. 2 cutoff)")
    q.add_argument("--out", type=Path, default=None,
                   help="JSON in the SerialRobotJoint FMU's parameter names (M, k, q_off, beta_*) for "
                        "writeback --values; the regressor estimates beside them")
    q.set_defaults(func=_identify_joint, output_files=("out",))
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
    q.set_defaults(func=_identify_frf, output_files=("out",))
    q = kinds.add_parser("oe", help="output-error refit of any Modelica plant's parameters (CasADi free run of the "
                                    "equations the FMU is built from; closed loop with --controller)",
                         description="Output-error refit. The RMS output error printed (and rms_output_error in "
                                     "--out) is that of the returned model's free run along the recording, its "
                                     "initial position and velocity estimated from the output alone (start as "
                                     "--initial says): the number motiontwin validate prints for --out on the same "
                                     "recording (one definition, ident.validation.free_run). A parameter that "
                                     "ends on a bound is printed 'at bound' with no std (the others' statistics "
                                     "are conditional on it).")
    q.add_argument("recording", type=Path, help="recording CSV, uniformly sampled")
    q.add_argument("--modelica", type=Path, default=MODELICA_DIR, help="Modelica library folder or .mo file")
    q.add_argument("--class", dest="class_name", required=True,
                   help="plant class, e.g. MotionTwin.Plants.LinearMotorJoint")
    q.add_argument("--free", required=True, help="comma-separated parameters to fit, e.g. m,d")
    q.add_argument("--input", default="u", help="plant input = recording column (default u)")
    q.add_argument("--output", default="q", help="plant output/state = recording column (default q)")
    q.add_argument("--controller", default=None,
                   help="controller JSON (discrete_state_space, or an experiment.json; its Ts the recording's step or a whole "
                        "fraction of it, a faster controller run at its own period); the recording then needs r. "
                        "'unknown' (or a JSON {\"kind\": \"unknown\"}): no controller known, the model runs as a "
                        "prediction-error predictor (measured force plus a PD observer on the measured position, "
                        "its bandwidth fitted by prediction error, ident.observer) so a double integrator does not "
                        "drift; needs only u and q")
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
    q.set_defaults(func=_identify_oe, output_files=("out",))

    q = kinds.add_parser("hexapod", help="hexapod base parameters from a periodic recording of leg lengths "
                                         "L1..L6 [m] and leg forces tau1..tau6 [N]")
    q.add_argument("recording", type=Path, help="recording CSV (whole number of periods)")
    q.add_argument("--f0", type=float, required=True, help="fundamental frequency of the excitation [Hz]")
    q.add_argument("--cutoff", type=float, required=True, help="low-pass cut-off of the derivatives [Hz]")
    q.add_argument("--min-speed", type=float, default=0.0, help="drop samples where a leg is slower [m/s]")
    q.add_argument("--out", type=Path, default=None, help="write estimates, std and covariance as JSON")
    q.set_defaults(func=_identify_hexapod, output_files=("out",))

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
    q.set_defaults(func=_identify_projection, output_files=("out",))

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
    q.set_defaults(func=_design_excitation, output_files=("out",))
