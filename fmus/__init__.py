"""Modelica-to-FMU pipeline: front end, symbolic model, C code generation, FMI runtime, packaging.

The constants below live here, not in :mod:`fmus.build`, so that the command line can show its defaults
(``motiontwin --help``) without importing CasADi.
"""
from pathlib import Path

# modelica/ sits beside fmus/ in the checkout and in the installed package (motiontwin/modelica).
MODELICA_DIR = Path(__file__).resolve().parent.parent / "modelica"
DEFAULT_OUT = Path("build") / "fmus"
FMI_VERSIONS = ("2.0", "3.0")
