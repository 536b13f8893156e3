"""Write fitted parameter values back into an FMU's start values: a new FMU, rebuilt from its own sources.

An FMU built by motiontwin carries its C sources, with the start values the binary uses by default in
``sources/model.c``. Write-back changes them there and in modelDescription.xml, gives the FMU a new
token, recompiles the binary from the archive's sources and packs a new archive atomically: the defaults
of the binary equal the XML start values, and the original FMU is never modified. Provenance (values,
method, recording, covariance) goes into ``documentation/provenance.json`` inside the FMU and into a JSON
sidecar; the values also go into a Modelica modifier that extends the source class.
"""
from __future__ import annotations

import hashlib
import json
import math
import re
import tempfile
import uuid
import xml.etree.ElementTree as ET
import zipfile
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from motiontwin.fmus import archive, codegen, description, package

PROVENANCE_FILE = "documentation/provenance.json"


class WriteBackError(ValueError):
    """The FMU or the values cannot be written back; the message names the FMU and the variable."""


def _variables(root: ET.Element) -> dict[str, ET.Element]:
    """name -> element holding the start attribute (Real in FMI 2.0, Float64 in FMI 3.0)."""
    out = {}
    for el in root.find("ModelVariables"):
        holder = el.find("Real") if el.tag == "ScalarVariable" else el
        if holder is not None:
            out[el.get("name")] = (el, holder)
    return out


def write_back(fmu: Path | str, values: dict[str, float], out: Path | str,
               provenance: dict[str, Any] | None = None) -> Path:
    """Write a copy of ``fmu`` to ``out`` whose parameters/states start at ``values``; return ``out``."""
    fmu, out = Path(fmu), Path(out)
    if fmu.resolve() == out.resolve():
        raise WriteBackError(f"{out}: write-back never overwrites the original FMU; choose another output path")
    archive.read_description(fmu)   # a non-zip file or a malformed description: one error naming the FMU
    with zipfile.ZipFile(fmu) as zf:
        files = {name: zf.read(name) for name in zf.namelist() if not name.endswith("/")}
    root = ET.fromstring(files["modelDescription.xml"])
    if root.get("generationTool") != description.GENERATION_TOOL or "sources/model.c" not in files:
        raise WriteBackError(f"{fmu}: only FMUs built by motiontwin (with their sources) can be written back")
    fmi3 = root.get("fmiVersion", "").startswith("3")
    variables = _variables(root)
    model_c = files["sources/model.c"].decode()
    starts = _start_array(model_c, fmu)
    for name, value in values.items():
        if name not in variables:
            raise WriteBackError(f"{fmu}: no variable named {name!r}")
        el, holder = variables[name]
        if el.get("causality") != "parameter" and not (el.get("initial") == "exact" and holder.get("start")):
            raise WriteBackError(f"{fmu}: {name} is a {el.get('causality')} without a start value to write")
        value = float(value)
        lo, hi = float(holder.get("min", -math.inf)), float(holder.get("max", math.inf))
        if not (math.isfinite(value) and lo <= value <= hi):
            raise WriteBackError(f"{fmu}: {name} = {value!r} is outside [{lo}, {hi}]")
        holder.set("start", repr(value))
        starts[int(el.get("valueReference"))] = codegen.c_double(value)
    token_key = "instantiationToken" if fmi3 else "guid"
    old_token = root.get(token_key)
    digest = hashlib.sha256((old_token + json.dumps(values, sort_keys=True)).encode()).digest()
    token = "{" + str(uuid.UUID(bytes=digest[:16], version=4)) + "}"
    root.set(token_key, token)
    root.set("generationDateAndTime", datetime.now(timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"))
    model_c = _replace_start_array(model_c, starts).replace(f'.token = "{old_token}"', f'.token = "{token}"')
    files["sources/model.c"] = model_c.encode()
    files["modelDescription.xml"] = b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, "utf-8")
    record = {"source_fmu": str(fmu), "source_token": old_token, "token": token, "values": values,
              **(provenance or {})}
    files[PROVENANCE_FILE] = (json.dumps(record, indent=2) + "\n").encode()
    identifier = root.find("CoSimulation").get("modelIdentifier")
    with tempfile.TemporaryDirectory(prefix="motiontwin-writeback-") as tmp:
        staging = Path(tmp)
        for name, data in files.items():
            if not name.startswith("binaries/"):
                (staging / name).parent.mkdir(parents=True, exist_ok=True)
                (staging / name).write_bytes(data)
        src = staging / "sources"
        c_files = sorted(p.name for p in src.glob("*.c"))
        platform = package.PLATFORM_DIR["3.0" if fmi3 else "2.0"]
        (staging / "binaries" / platform).mkdir(parents=True)
        package.compile_binary(src, c_files, staging / "binaries" / platform / f"{identifier}.so")
        package.pack(staging, out)
    return out


_START = re.compile(r"static const double start\[\] = \{\n(.*?)\n\};", re.S)


def _start_array(model_c: str, fmu: Path) -> list[str]:
    match = _START.search(model_c)
    if not match:
        raise WriteBackError(f"{fmu}: sources/model.c has no start-value table")
    return [item.strip() for item in match.group(1).split(",")]


def _replace_start_array(model_c: str, starts: list[str]) -> str:
    body = ",\n    ".join(starts)
    return _START.sub(lambda _: f"static const double start[] = {{\n    {body}\n}};", model_c, count=1)


def modelica_modifier(class_name: str, values: dict[str, float], provenance: dict[str, Any] | None = None) -> str:
    """Modelica source of a class that extends ``class_name`` with the fitted values as modifiers."""
    short = class_name.rsplit(".", 1)[-1]
    note = json.dumps({k: v for k, v in (provenance or {}).items() if isinstance(v, (str, int, float))})
    mods = ",\n    ".join(f"{name} = {float(value)!r}" for name, value in values.items())
    return (f'model {short}Fitted "{short} with fitted parameters (motiontwin write-back)"\n'
            f"  extends {class_name}(\n    {mods});\n"
            f'  annotation(Documentation(info = "{note.replace(chr(34), chr(39))}"));\n'
            f"end {short}Fitted;\n")
