"""``motiontwin validate``: re-simulate a fitted model on a new recording (fit %, RMS, residual tests, plot)."""
from __future__ import annotations

import argparse
from pathlib import Path


def _validate(args: argparse.Namespace) -> int:
    import json

    from motiontwin.cli.arguments import name_values
    from motiontwin.fmus import build
    from motiontwin.harness.recording import atomic_write_texts, read_recording
    from motiontwin.ident import validation
    from motiontwin.ident.controller import load_controller
    from motiontwin.ident.outputerror import Signals

    values: dict[str, float] = {}
    for item in args.set:
        values |= name_values(item, "--set")
    model_path = None if args.model == "-" else Path(args.model)
    spec = validation.load_model_spec(model_path, class_name=args.class_name, modelica=args.modelica, values=values)
    controller = load_controller(args.controller) if args.controller else None
    signals = Signals(output=args.output, input=args.input, reference=args.reference)
    required = [signals.output, signals.input] + ([signals.reference] if controller else [])
    rec = read_recording(args.recording, required)
    model = build.load_model(spec.class_name, spec.modelica)
    result = validation.validate(model, spec, rec, controller=controller, signals=signals, lags=args.lags,
                                 estimate_initial=not args.initial_from_data)
    auto, cross = result.autocorrelation, result.cross_correlation
    print(f"{spec.class_name} ({spec.source}) on {args.recording}, {'closed' if controller else 'open'} loop, "
          f"{result.time.size} samples")
    print(f"fit {result.fit_percent:.3f} % (NRMSE), RMS error {result.rms:.4g} {rec.units.get(signals.output, '')}"
          + "".join(f", {k}(t0) = {v:.6g}" for k, v in result.initial.items()))
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
                       description="MODEL is a values JSON (identify oe --out), an FMU (writeback, diagnose: "
                                   "modelName and parameter start values), or '-' with --class. The model is "
                                   "re-simulated with the output-error free run (ident.outputerror), open loop from "
                                   "the measured input or closed loop with --controller; only the initial position "
                                   "and velocity are estimated. See ident/validation.py for the tests.")
    p.add_argument("model", help="values JSON, FMU, or '-' (then --class)")
    p.add_argument("recording", type=Path, help="recording CSV, uniformly sampled (a different one than fitted on)")
    p.add_argument("--class", dest="class_name", default=None, help="Modelica class (default: the model file's)")
    p.add_argument("--modelica", type=Path, default=None,
                   help="Modelica library folder or .mo file of the class (default: the JSON's, else the library)")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="override a parameter value")
    p.add_argument("--controller", type=Path, default=None,
                   help="closed loop: controller JSON (discrete_state_space, or a library controller by name)")
    p.add_argument("--input", default="u", help="plant input column (default u)")
    p.add_argument("--output", default="q", help="plant output column (default q)")
    p.add_argument("--reference", default="r", help="reference column in closed loop (default r)")
    p.add_argument("--lags", type=int, default=25, help="correlation lags M (default 25, as SITB resid)")
    p.add_argument("--initial-from-data", action="store_true",
                   help="start at the first sample at rest instead of estimating the initial position "
                        "and velocity")
    p.add_argument("--out", type=Path, default=None, help="JSON with fit %%, RMS and both tests")
    p.add_argument("--plot", type=Path, default=None, help="PNG: compare plot and the two correlation plots")
    p.set_defaults(func=_validate)
