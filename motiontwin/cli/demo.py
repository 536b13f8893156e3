"""``motiontwin demo``: the end-to-end example."""
from __future__ import annotations

import argparse
from pathlib import Path


def _demo(args: argparse.Namespace) -> int:
    from motiontwin import demo

    demo.run(Path(args.out))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add this module's subcommands to the ``motiontwin`` parser."""
    p = sub.add_parser("demo", help="build the example FMUs and run the example end to end")
    p.add_argument("--out", type=Path, default=Path("build") / "demo")
    p.set_defaults(func=_demo, output_folders=("out",))
