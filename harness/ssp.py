"""Export a harness system as an SSP 1.0 archive (System Structure and Parameterization) for other tools.

The archive holds ``SystemStructure.ssd`` and ``resources/<instance>.fmu`` (a copy of every FMU).
Mapping from the system file:

* each FMU instance -> an ``ssd:Component`` with its connected/logged Real ports as connectors and
  its parameter overrides as an inline ``ssv:ParameterSet``;
* each external input ``input.NAME`` -> a system input connector ``NAME``;
* a single-source connection -> an ``ssd:Connection`` (a gain other than 1 becomes an
  ``ssc:LinearTransformation``);
* units that parse as SI (see :func:`harness.units.canonical_unit`) -> ``ssc:Unit`` definitions;
* ``start_time``/``stop_time`` -> ``ssd:DefaultExperiment``.

SSP 1.0 has no sum junction (an input takes one connection). A connection with several sources is
refused with an error, unless ``drop_external_in_sums=True``: then external-input sources are left out
of sums (e.g. plant force = controller output + u_ext becomes plant force = controller output, the
loop without excitation). Communication steps are not part of SSP 1.0; importers choose their own.
The archive is written to a temporary file and moved into place (atomic).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path

from motiontwin.fmus.archive import read_description
from motiontwin.fmus.files import atomic_path

from .units import canonical_unit
from .system import INPUT_NAMESPACE, System, load_system, split_port

SSD = "http://ssp-standard.org/SSP1/SystemStructureDescription"
SSC = "http://ssp-standard.org/SSP1/SystemStructureCommon"
SSV = "http://ssp-standard.org/SSP1/SystemStructureParameterValues"
_BASE_UNITS = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")

ET.register_namespace("ssd", SSD)
ET.register_namespace("ssc", SSC)
ET.register_namespace("ssv", SSV)


class SSPExportError(ValueError):
    """The system uses a feature SSP 1.0 cannot express."""


def _q(ns: str, tag: str) -> str:
    return f"{{{ns}}}{tag}"


def _single_source_connections(system: System, drop_external_in_sums: bool) -> list[tuple[str, str, float]]:
    out = []
    for c in system.connections:
        pairs = list(zip(c.sources, c.gains))
        if len(pairs) > 1 and drop_external_in_sums:
            pairs = [(s, g) for s, g in pairs if split_port(s)[0] != INPUT_NAMESPACE]
        if len(pairs) != 1:
            raise SSPExportError(
                f"connection to '{c.to}' sums {list(c.sources)}; SSP 1.0 has no sum junction "
                f"(pass drop_external_in_sums=True, or --drop-external-in-sums, to leave external inputs out of sums)")
        out.append((pairs[0][0], c.to, pairs[0][1]))
    return out


def system_structure(system: System, drop_external_in_sums: bool = False) -> ET.Element:
    """The ``SystemStructure.ssd`` document of ``system``."""
    connections = _single_source_connections(system, drop_external_in_sums)
    models = {n: read_description(spec.path) for n, spec in system.fmus.items()}
    variables = {n: {v.name: v for v in md.modelVariables} for n, md in models.items()}
    ports: dict[str, dict[str, str]] = {n: {} for n in system.fmus}  # instance -> variable -> kind
    for source, target, _ in connections:
        for port, kind in ((source, "output"), (target, "input")):
            inst, var = split_port(port)
            if inst != INPUT_NAMESPACE:
                if var not in variables[inst]:
                    raise SSPExportError(f"unknown port '{port}'")
                ports[inst][var] = kind
    for group in system.logs:
        for port in group.signals:
            inst, var = split_port(port)
            if inst != INPUT_NAMESPACE and var in variables[inst] and variables[inst][var].causality in ("input", "output"):
                ports[inst].setdefault(var, variables[inst][var].causality)

    units: dict[str, dict[str, int]] = {}

    def unit_attr(unit: str | None) -> dict[str, str]:
        if not unit:
            return {}
        canonical = canonical_unit(unit)
        if canonical is None or any(name not in _BASE_UNITS for name, _ in canonical):
            return {}
        units[unit] = dict(canonical)
        return {"unit": unit}

    root = ET.Element(_q(SSD, "SystemStructureDescription"), version="1.0", name=_system_name(system))
    sys_el = ET.SubElement(root, _q(SSD, "System"), name=_system_name(system))
    used_inputs = [split_port(s)[1] for s, _, _ in connections if split_port(s)[0] == INPUT_NAMESPACE]
    if used_inputs:
        connectors = ET.SubElement(sys_el, _q(SSD, "Connectors"))
        for name in dict.fromkeys(used_inputs):
            c = ET.SubElement(connectors, _q(SSD, "Connector"), name=name, kind="input")
            ET.SubElement(c, _q(SSC, "Real"), unit_attr(system.inputs[name].unit))
    elements = ET.SubElement(sys_el, _q(SSD, "Elements"))
    for name, spec in system.fmus.items():
        comp = ET.SubElement(elements, _q(SSD, "Component"), name=name,
                             type="application/x-fmu-sharedlibrary", source=f"resources/{name}.fmu")
        if ports[name]:
            connectors = ET.SubElement(comp, _q(SSD, "Connectors"))
            for var, kind in ports[name].items():
                c = ET.SubElement(connectors, _q(SSD, "Connector"), name=var, kind=kind)
                v = variables[name][var]
                unit = v.unit or getattr(getattr(v, "declaredType", None), "unit", None)
                ET.SubElement(c, _q(SSC, "Real"), unit_attr(unit))
        if spec.parameters:
            bindings = ET.SubElement(comp, _q(SSD, "ParameterBindings"))
            binding = ET.SubElement(bindings, _q(SSD, "ParameterBinding"))
            values = ET.SubElement(binding, _q(SSD, "ParameterValues"))
            pset = ET.SubElement(values, _q(SSV, "ParameterSet"), version="1.0", name=f"{name}_parameters")
            params = ET.SubElement(pset, _q(SSV, "Parameters"))
            for pname, value in spec.parameters.items():
                if pname not in variables[name]:
                    raise SSPExportError(f"[fmus.{name}.parameters] {pname}: no such variable in {spec.path}")
                p = ET.SubElement(params, _q(SSV, "Parameter"), name=pname)
                kind = variables[name][pname].type
                if isinstance(value, bool) or kind == "Boolean":
                    ET.SubElement(p, _q(SSV, "Boolean"), value="true" if value else "false")
                elif kind in ("Real", "Float64", "Float32"):
                    ET.SubElement(p, _q(SSV, "Real"), value=repr(float(value)))
                elif kind == "String":
                    ET.SubElement(p, _q(SSV, "String"), value=str(value))
                else:
                    ET.SubElement(p, _q(SSV, "Integer"), value=str(int(value)))
    if connections:
        conns = ET.SubElement(sys_el, _q(SSD, "Connections"))
        for source, target, gain in connections:
            s_inst, s_var = split_port(source)
            t_inst, t_var = split_port(target)
            attrs = {"startConnector": s_var, "endElement": t_inst, "endConnector": t_var}
            if s_inst != INPUT_NAMESPACE:
                attrs = {"startElement": s_inst, **attrs}
            conn = ET.SubElement(conns, _q(SSD, "Connection"), attrs)
            if gain != 1.0:
                ET.SubElement(conn, _q(SSC, "LinearTransformation"), factor=repr(gain))
    if units:
        units_el = ET.SubElement(root, _q(SSD, "Units"))
        for unit, powers in units.items():
            u = ET.SubElement(units_el, _q(SSC, "Unit"), name=unit)
            ET.SubElement(u, _q(SSC, "BaseUnit"), {k: str(v) for k, v in powers.items()})
    experiment = {"startTime": repr(system.start_time)}
    if system.stop_time is not None:
        experiment["stopTime"] = repr(system.stop_time)
    ET.SubElement(root, _q(SSD, "DefaultExperiment"), experiment)
    ET.indent(root)
    return root


def _system_name(system: System) -> str:
    return system.source.stem if system.source else "system"


def export_ssp(system: System | str | Path, path: str | Path, drop_external_in_sums: bool = False) -> Path:
    """Write ``system`` as an SSP archive at ``path`` (atomically) and return the path."""
    system = system if isinstance(system, System) else load_system(system)
    root = system_structure(system, drop_external_in_sums)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp, zipfile.ZipFile(tmp, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        zf.writestr("SystemStructure.ssd", ET.tostring(root, encoding="utf-8", xml_declaration=True))
        for name, spec in system.fmus.items():
            zf.write(spec.path, f"resources/{name}.fmu")
    return path
