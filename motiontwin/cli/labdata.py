"""``motiontwin import``: a lab file (.mat, HDF5, CSV with other column names) -> a recording."""
from __future__ import annotations

import argparse
from pathlib import Path


def _pairs(items: list[str], option: str) -> dict[str, str]:
    """``["q=pos_enc", ...]`` -> ``{"q": "pos_enc"}``; ValueError naming the option otherwise."""
    out: dict[str, str] = {}
    for item in items:
        name, sep, value = item.partition("=")
        if not sep or not name.strip() or not value.strip():
            raise ValueError(f"{option} {item!r}: expected NAME=VALUE")
        out[name.strip()] = value.strip()
    return out


def _import(args: argparse.Namespace) -> int:
    from motiontwin.harness import labdata, recording

    period = args.period if args.period is not None else (1.0 / args.f0 if args.f0 is not None else None)
    if args.f0 is not None and args.f0 <= 0:
        raise ValueError(f"--f0 must be > 0 Hz, got {args.f0}")
    result = labdata.import_lab_file(
        args.file, mapping=_pairs(args.column, "--column"), time=args.time, units=_pairs(args.unit, "--unit"),
        gains=_pairs(args.gain, "--gain"), window=tuple(args.window) if args.window else None, period=period,
        resample=args.resample, sample_time=args.sample_time, excited=args.excited)
    for note in result.notes:
        print(note)
    rec = result.recording
    print(f"{rec.time.size} samples, {rec.time[0]:.6g}..{rec.time[-1]:.6g} s, columns "
          + ", ".join(f"{n} [{rec.units[n]}]" for n in rec.columns))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    for path in recording.write_recording(args.out, rec):
        print(path)
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``import`` to the ``motiontwin`` parser."""
    p = sub.add_parser("import", help="turn a lab file (.mat, HDF5, CSV/TSV with any column names) into a recording",
                       description="Read a lab file, map its columns, apply gains and units (to SI), measure the "
                                   "sample time and its jitter, optionally resample, trim to a window and to whole "
                                   "periods, and write NAME.csv + NAME.json (harness.labdata).")
    p.add_argument("file", type=Path, help=".mat (v4-v7.3), .h5/.hdf5, or delimited text with a header line")
    p.add_argument("--out", type=Path, required=True, help="recording CSV (a JSON sidecar is written beside it)")
    p.add_argument("--time", default=None, metavar="NAME",
                   help="source name of the time vector (default: time or t)")
    p.add_argument("--column", action="append", default=[], metavar="NAME=SOURCE",
                   help="recording column NAME from source vector SOURCE (struct fields a.b, HDF5 /g/d, matrix "
                        "columns data(:,2)); repeatable; default: every vector, own names")
    p.add_argument("--unit", action="append", default=[], metavar="NAME=UNIT",
                   help="recorded unit of column NAME (or time), e.g. u=V, q=mm, time=ms; mm, um, deg, kN, ms... "
                        "are converted to SI")
    p.add_argument("--gain", action="append", default=[], metavar="NAME=GAIN",
                   help="multiply column NAME by GAIN with its unit RESULT/RECORDED, e.g. u='40 N/V'")
    p.add_argument("--window", type=float, nargs=2, default=None, metavar=("START", "STOP"),
                   help="keep START <= t <= STOP [s]")
    trim = p.add_mutually_exclusive_group()
    trim.add_argument("--period", type=float, default=None, help="excitation period [s]: trim to whole periods")
    trim.add_argument("--f0", type=float, default=None, help="excitation fundamental [Hz]: trim to whole periods")
    p.add_argument("--resample", action="store_true",
                   help="interpolate linearly onto a uniform grid: the ticks k*TS of --sample-time, else t0 + k*Ts "
                        "with Ts the median step snapped to its clock; off by default")
    p.add_argument("--sample-time", type=float, default=None, metavar="TS",
                   help="sample time [s], e.g. the controller's period: the grid of --resample (two recordings of "
                        "one experiment then share it); without --resample the median step must lie within the "
                        "jitter of TS. Default: the median step, snapped to the clock when within the jitter "
                        "(0.000999984 -> 0.001, reported)")
    p.add_argument("--excited", default=None, help="what was excited (free text, stored in the sidecar)")
    p.set_defaults(func=_import)
