"""modelDescription.xml (FMI 2.0 and 3.0) and buildDescription.xml from a variable :class:`~fmus.layout.Layout`.

The capability flags state what the C runtime really implements: Model Exchange and
Co-Simulation in one binary, variable communication steps, get/set and serialised FMU state,
directional (and, in FMI 3.0, adjoint) derivatives from CasADi's AD.
"""
from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from datetime import datetime, timezone

from motiontwin.fmus.layout import FmuVariable, Layout

GENERATION_TOOL = "motiontwin"
LOG_CATEGORIES = {"logEvents": "events and sample instants", "logStatusError": "errors"}

# SI base-unit exponents (kg, m, s, A, K, mol, cd, rad) of the unit symbols the library uses.
_BASE = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")
_SYMBOLS: dict[str, tuple[dict[str, int], float]] = {
    "kg": ({"kg": 1}, 1.0), "g": ({"kg": 1}, 1e-3), "m": ({"m": 1}, 1.0), "mm": ({"m": 1}, 1e-3),
    "um": ({"m": 1}, 1e-6), "s": ({"s": 1}, 1.0), "ms": ({"s": 1}, 1e-3), "A": ({"A": 1}, 1.0),
    "K": ({"K": 1}, 1.0), "mol": ({"mol": 1}, 1.0), "cd": ({"cd": 1}, 1.0), "rad": ({"rad": 1}, 1.0),
    "deg": ({"rad": 1}, math.pi / 180), "N": ({"kg": 1, "m": 1, "s": -2}, 1.0), "Hz": ({"s": -1}, 1.0),
    "J": ({"kg": 1, "m": 2, "s": -2}, 1.0), "W": ({"kg": 1, "m": 2, "s": -3}, 1.0),
    "V": ({"kg": 1, "m": 2, "s": -3, "A": -1}, 1.0), "Pa": ({"kg": 1, "m": -1, "s": -2}, 1.0), "1": ({}, 1.0),
}


def unit_exponents(unit: str) -> tuple[dict[str, int], float] | None:
    """SI base-unit exponents and factor of a Modelica unit string (``"N.s/m"``), or None if unknown."""

    def factors(expr: str, sign: int, acc: dict[str, int]) -> float | None:
        factor = 1.0
        for token in filter(None, expr.strip("()").split(".")):
            m = re.fullmatch(r"([A-Za-z]+|1)(-?\d+)?", token)
            if not m or m.group(1) not in _SYMBOLS:
                return None
            exps, f = _SYMBOLS[m.group(1)]
            power = int(m.group(2) or 1) * sign
            for base, e in exps.items():
                acc[base] = acc.get(base, 0) + e * power
            factor *= f ** power
        return factor

    acc: dict[str, int] = {}
    num, _, den = unit.partition("/")
    f1 = factors(num, 1, acc)
    f2 = factors(den, -1, acc) if den else 1.0
    if f1 is None or f2 is None:
        return None
    return {k: v for k, v in acc.items() if v}, f1 * f2


def _fmt(x: float) -> str:
    return repr(float(x))


def _unit_definitions(root: ET.Element, layout: Layout) -> None:
    units = sorted({v.unit for v in layout.variables if v.unit})
    if not units:
        return
    defs = ET.SubElement(root, "UnitDefinitions")
    for unit in units:
        el = ET.SubElement(defs, "Unit", name=unit)
        parsed = unit_exponents(unit)
        if parsed is not None:
            exps, factor = parsed
            attrs = {k: str(exps[k]) for k in _BASE if k in exps}
            if factor != 1.0:
                attrs["factor"] = _fmt(factor)
            ET.SubElement(el, "BaseUnit", attrs)


def _common_attrs(v: FmuVariable) -> dict[str, str]:
    attrs = {"name": v.name, "valueReference": str(v.vr)}
    if v.description:
        attrs["description"] = v.description
    attrs["causality"] = v.causality
    attrs["variability"] = v.variability
    if v.initial and not (v.causality in ("input", "independent")):
        attrs["initial"] = v.initial
    return attrs


def _type_attrs(v: FmuVariable) -> dict[str, str]:
    attrs: dict[str, str] = {}
    if v.unit:
        attrs["unit"] = v.unit
    if v.derivative_of is not None:
        attrs["derivative"] = str(v.derivative_of)
    if math.isfinite(v.min):
        attrs["min"] = _fmt(v.min)
    if math.isfinite(v.max):
        attrs["max"] = _fmt(v.max)
    if v.nominal:
        attrs["nominal"] = _fmt(abs(v.nominal))
    if v.start is not None and v.initial != "calculated":
        attrs["start"] = _fmt(v.start)
    return attrs


def model_description(layout: Layout, *, fmi_version: str, identifier: str, model_name: str, token: str,
                      description: str, step_size: float) -> bytes:
    """modelDescription.xml for ``fmi_version`` "2.0" or "3.0", as UTF-8 bytes."""
    fmi3 = fmi_version == "3.0"
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": fmi_version,
        "modelName": model_name,
        ("instantiationToken" if fmi3 else "guid"): token,
        "description": description or identifier,
        "generationTool": GENERATION_TOOL,
        "generationDateAndTime": datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "variableNamingConvention": "structured",
        **({} if fmi3 else {"numberOfEventIndicators": "0"}),
    })
    nx = len(layout.block("x"))
    state_flags = {("canGetAndSetFMUState" if fmi3 else "canGetAndSetFMUstate"): "true",
                   ("canSerializeFMUState" if fmi3 else "canSerializeFMUstate"): "true",
                   ("providesDirectionalDerivatives" if fmi3 else "providesDirectionalDerivative"): "true"}
    if fmi3:
        state_flags["providesAdjointDerivatives"] = "true"
    me = {"modelIdentifier": identifier, **state_flags}
    if fmi3:
        me["needsCompletedIntegratorStep"] = "false"
    else:
        me["completedIntegratorStepNotNeeded"] = "true"
    cs = {"modelIdentifier": identifier, "canHandleVariableCommunicationStepSize": "true", **state_flags}
    if not fmi3:
        cs["canInterpolateInputs"] = "false"
    ET.SubElement(root, "ModelExchange", me)
    ET.SubElement(root, "CoSimulation", cs)
    _unit_definitions(root, layout)
    cats = ET.SubElement(root, "LogCategories")
    for name, text in LOG_CATEGORIES.items():
        ET.SubElement(cats, "Category", name=name, description=text)
    ET.SubElement(root, "DefaultExperiment", startTime="0.0", stopTime="1.0", tolerance="1e-08",
                  stepSize=_fmt(step_size))
    mv = ET.SubElement(root, "ModelVariables")
    for v in layout.variables:
        if v.block == "time" and not fmi3:
            continue
        attrs = _common_attrs(v)
        if fmi3:
            attrs.update(_type_attrs(v))
            ET.SubElement(mv, "Float64", attrs)
        else:
            ET.SubElement(ET.SubElement(mv, "ScalarVariable", attrs), "Real", _type_attrs(v))
    _model_structure(root, layout, fmi3, nx)
    ET.indent(root)
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="utf-8")


def _model_structure(root: ET.Element, layout: Layout, fmi3: bool, nx: int) -> None:
    ms = ET.SubElement(root, "ModelStructure")
    outputs = [v for v in layout.variables if v.causality == "output"]
    derivatives = layout.block("dx")
    initial = [v for v in layout.variables
               if (v.causality == "output" and v.initial == "calculated")
               or v.causality == "calculatedParameter"
               or v.block == "dx"
               or (v.block == "x" and v.initial == "calculated")]
    # FMI 2.0 refers to variables by their 1-based index in ModelVariables; with time left out that is the vr.
    ref = "valueReference" if fmi3 else "index"

    def deps(v: FmuVariable) -> dict[str, str]:
        if v.dependencies is None:
            return {}
        return {"dependencies": " ".join(str(d) for d in v.dependencies)}

    if fmi3:
        for v in outputs:
            ET.SubElement(ms, "Output", {ref: str(v.vr), **deps(v)})
        for v in derivatives:
            ET.SubElement(ms, "ContinuousStateDerivative", {ref: str(v.vr)})
        for v in initial:
            ET.SubElement(ms, "InitialUnknown", {ref: str(v.vr)})
        return
    for tag, items, with_deps in (("Outputs", outputs, True), ("Derivatives", derivatives, False),
                                  ("InitialUnknowns", initial, False)):
        if items:
            parent = ET.SubElement(ms, tag)
            for v in items:
                ET.SubElement(parent, "Unknown", {ref: str(v.vr), **(deps(v) if with_deps else {})})


def build_description(identifier: str, sources: list[str]) -> bytes:
    """sources/buildDescription.xml (FMI 3.0) listing the C files to compile."""
    root = ET.Element("fmiBuildDescription", fmiVersion="3.0")
    config = ET.SubElement(root, "BuildConfiguration", modelIdentifier=identifier)
    files = ET.SubElement(config, "SourceFileSet", language="C99")
    for name in sources:
        ET.SubElement(files, "SourceFile", name=name)
    ET.SubElement(config, "Library", name="m")
    ET.indent(root)
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="utf-8")


def add_source_files(xml: bytes, sources: list[str]) -> bytes:
    """FMI 2.0: list the C sources in ``<SourceFiles>`` of both interface elements."""
    root = ET.fromstring(xml)
    for tag in ("ModelExchange", "CoSimulation"):
        el = root.find(tag)
        files = ET.SubElement(el, "SourceFiles")
        for name in sources:
            ET.SubElement(files, "File", name=name)
    ET.indent(root)
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="utf-8")
