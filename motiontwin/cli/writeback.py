"""``motiontwin writeback``: write fitted values into a new FMU."""
from __future__ import annotations

import argparse
from pathlib import Path

from motiontwin.cli.arguments import name_values


def _writeback(args: argparse.Namespace) -> int:
    import json

    from motiontwin.fmus import writeback
    from motiontwin.fmus.archive import read_description
    from motiontwin.fmus.limits import load_json
    from motiontwin.harness.recording import atomic_write_texts
    from motiontwin.ident.startvalues import read_values_file

    values: dict[str, float] = {}
    provenance: dict[str, object] = {}
    if args.values:
        values = read_values_file(args.values)   # a checked JSON object, read again for the provenance
        doc = load_json(args.values)
        provenance = {k: doc[k] for k in ("method", "recording", "names", "std", "covariance") if k in doc}
        provenance["values_file"] = str(args.values)
    for item in args.set:
        values |= name_values(item, "--set")
    for item in args.rename:
        old, sep, new = item.partition("=")
        if not sep or old not in values:
            raise ValueError(f"--rename {item!r}: expected FROM=TO with FROM among {sorted(values)}")
        values[new] = values.pop(old)
    values = {k: v for k, v in values.items() if k not in args.drop}
    if not values:
        raise ValueError("nothing to write back: give --values FILE and/or --set NAME=VALUE")
    out = writeback.write_back(args.fmu, values, args.out, provenance)
    class_name = read_description(out).modelName
    modifier = args.modelica_out or args.out.with_suffix(".mo")
    atomic_write_texts({modifier: writeback.modelica_modifier(class_name, values, provenance),
                        args.out.with_suffix(".provenance.json"):
                            json.dumps({"fmu": str(out), "values": values, **provenance}, indent=2) + "\n"})
    print(out)
    print(modifier)
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add this module's subcommands to the ``motiontwin`` parser."""
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
    p.set_defaults(func=_writeback, output_files=("out", "modelica_out"), input_fmus=("fmu",))
