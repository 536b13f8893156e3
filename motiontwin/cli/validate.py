"""``motiontwin validate``: re-simulate a fitted model on a new recording (fit %, RMS, residual tests, plot)."""
from __future__ import annotations

import argparse
from pathlib import Path


def _validate(args: argparse.Namespace) -> int:
    import json

    from motiontwin.cli.arguments import loop_controller, name_values
    from motiontwin.harness.recording import atomic_write_texts, read_recording
    from motiontwin.ident import channels, validation

    values: dict[str, float] = {}
    for item in args.set:
        values |= name_values(item, "--set")
    model_path = None if args.model == "-" else Path(args.model)
    spec = validation.load_model_spec(model_path, class_name=args.class_name, modelica=args.modelica, values=values)
    known = args.controller is not None and args.controller != "unknown"
    rec = read_recording(args.recording, [args.output, args.input] + ([args.reference] if known else []))
    controller, signals, observer = loop_controller(args.controller, rec, args.output, args.input, args.reference,
                                                    fitted=spec.controller)
    model = validation.load_model(spec)
    horizon = None
    if observer is not None:
        horizon = max(1, round(args.horizon / observer.ts))
    result = validation.validate(model, spec, rec, controller=controller, signals=signals, lags=args.lags,
                                 estimate_initial=not args.initial_from_data, initial=args.initial, horizon=horizon)
    auto, cross = result.autocorrelation, result.cross_correlation
    ext = f" + {signals.disturbance}" if signals.disturbance in rec.columns else ""
    loop = "prediction-error predictor" if observer else "closed loop" if controller else "open loop"
    print(f"{spec.class_name} ({spec.source}) on {args.recording}, {loop}, {result.time.size} samples")
    print(f"fit {result.fit_percent:.3f} % (NRMSE), RMS output error {result.rms:.4g} "
          f"{rec.units.get(signals.output, '')} ({result.rms_definition})"
          + "".join(f", {k}(t0) = {v:.6g}" for k, v in result.initial.items()))
    if observer:
        print(f"{observer.describe()}; columns {signals.input}, {signals.output} -> {signals.output}")
        k = result.prediction
        print(f"k-step-ahead, the model alone restarted every {k.horizon} samples ({k.horizon * observer.ts:.4g} s) "
              f"from the predictor's state: RMS over the segments {k.segment_rms:.4g}, at {k.horizon} samples "
              f"ahead {k.horizon_rms:.4g} {rec.units.get(signals.output, '')}")
    elif controller:
        problem = channels.channel_problem(rec, controller, signals)
        fed = f"{signals.reference}{', ' + signals.disturbance if ext else ''}"
        print(f"columns {fed} -> {signals.output}, {signals.input} only checked; channel check: "
              + (problem or f"{signals.input} = controller({signals.reference}, {signals.output}){ext} within noise"))
    else:
        print(f"columns {signals.input} -> {signals.output}")
    print(f"residual autocorrelation, lags 1..{args.lags}: Q = {auto.statistic:.2f} vs 99 % limit "
          f"{auto.threshold:.2f}: {'white' if auto.passed else 'NOT white'}; {len(auto.outside)} lags outside "
          f"the 99 % band +-{auto.band:.3g}")
    print(f"cross-correlation {result.input} -> residual, lags -{args.lags}..{args.lags}: max |r|/sigma = "
          f"{cross.statistic:.2f} vs {cross.threshold:.2f}: {'independent' if cross.passed else 'NOT independent'}; "
          f"{len(cross.outside)} lags outside the 99 % band +-{cross.band:.3g}")
    texts = {}
    if args.out:
        texts[args.out] = json.dumps(validation.validation_document(result, str(args.recording)), indent=2) + "\n"
    if texts:
        atomic_write_texts(texts)
        print(args.out)
    if args.plot:
        print(validation.plot_validation(result, args.plot))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``validate`` to the ``motiontwin`` parser."""
    p = sub.add_parser("validate", help="re-simulate a fitted model on a new recording: fit %%, RMS, residual "
                                        "auto/cross-correlation tests, plot (like SITB compare/resid)",
                       description="MODEL is a values JSON (identify oe --out), an FMU (writeback, or the "
                                   "Augmented.fmu diagnose writes: modelName and parameter start values; its "
                                   "Modelica source is found next to it as NAME.mo or augmented_model/NAME.mo, "
                                   "else in the library, else give --modelica), the output folder of diagnose "
                                   "(its FMU and augmented_model/), or '-' with --class. The model is "
                                   "re-simulated with the output-error free run (ident.outputerror): open loop "
                                   "from the --input column (default u) to the --output column (default q); "
                                   "closed loop with --controller from the --reference column (default r) and, "
                                   "when recorded, u_ext added to the controller's force, u then only checked "
                                   "against controller(r, q) + u_ext (the channel check line, ident.channels). "
                                   "Only the initial position and velocity are estimated, from the output alone. "
                                   "The RMS output "
                                   "error is the one identify oe prints for the model it returns (same free run, "
                                   "same initial-state estimate: ident.validation.free_run). See "
                                   "ident/validation.py for the tests.")
    p.add_argument("model", help="values JSON, FMU, diagnose output folder, or '-' (then --class)")
    p.add_argument("recording", type=Path, help="recording CSV, uniformly sampled (a different one than fitted on)")
    p.add_argument("--class", dest="class_name", default=None, help="Modelica class (default: the model file's)")
    p.add_argument("--modelica", type=Path, default=None,
                   help="Modelica library folder or .mo file of the class (a file is read with the .mo files "
                        "beside it; default: the JSON's, the FMU's neighbour, else the library)")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="override a parameter value")
    p.add_argument("--controller", default=None,
                   help="closed loop: controller JSON (discrete_state_space, or a library controller by name; its Ts may be "
                        "the recording's step or a whole fraction of it, a faster controller run at its own period); "
                        "'unknown' (or a JSON {\"kind\": \"unknown\"}): the prediction-error predictor "
                        "(measured force u plus a PD observer on the measured q, ident.observer; columns u, "
                        "q only): the RMS is then the predictor's and the k-step-ahead scores are printed")
    p.add_argument("--horizon", type=float, default=0.05,
                   help="with --controller unknown: the k-step-ahead horizon [s] (default 0.05)")
    p.add_argument("--input", default="u", help="plant input column (default u; closed loop: checked only)")
    p.add_argument("--output", default="q", help="plant output column (default q)")
    p.add_argument("--reference", default="r", help="reference column in closed loop (default r)")
    p.add_argument("--lags", type=int, default=25, help="correlation lags M (default 25, as SITB resid)")
    p.add_argument("--initial", choices=("samples", "rest"), default=None,
                   help="start of the initial-state estimate, as identify oe --initial (default: the values "
                        "JSON's, else samples)")
    p.add_argument("--initial-from-data", action="store_true",
                   help="do not estimate the initial position and velocity: start at the first sample (velocity "
                        "as --initial says), as motiontwin diagnose scores its validation RMS")
    p.add_argument("--out", type=Path, default=None, help="JSON with fit %%, RMS and both tests")
    p.add_argument("--plot", type=Path, default=None, help="PNG: compare plot and the two correlation plots")
    p.set_defaults(func=_validate)
