"""``motiontwin build``: Modelica class -> FMI 2.0 / 3.0 FMU (Model Exchange + Co-Simulation, with sources).

Pipeline: :mod:`fmus.frontend` (pymoca) -> :mod:`fmus.symbolic` (explicit CasADi model) ->
:mod:`fmus.layout` (value references) -> :mod:`fmus.codegen` (C) + :mod:`fmus.description` (XML)
-> :mod:`fmus.package` (gcc, zip). Classes to export carry ``annotation(__motiontwin(export=true))``.
"""
from __future__ import annotations

import multiprocessing
import os
import tempfile
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path

from motiontwin.fmus import codegen, description, frontend, layout, package, symbolic
from motiontwin.fmus.files import move_file, staging_folder

from motiontwin.fmus import DEFAULT_OUT, FMI_VERSIONS, MODELICA_DIR  # noqa: F401 (re-exported)


@dataclass
class BuiltFmu:
    path: Path
    identifier: str
    fmi_version: str


def identifier_of(class_name: str) -> str:
    """modelIdentifier of a class: its last name component (a valid C identifier)."""
    return class_name.rsplit(".", 1)[-1]


def build_fmu(model: symbolic.SymbolicModel, out_dir: Path | str = DEFAULT_OUT, fmi_version: str = "3.0",
              identifier: str | None = None, start_values: dict[str, float] | None = None,
              description_text: str | None = None) -> BuiltFmu:
    """Build one FMU of ``model`` into ``out_dir/fmi2`` or ``out_dir/fmi3``; returns its path.

    ``start_values`` override parameter/state start values; they are compiled into the binary and
    written to the XML, so the defaults of the binary always equal the XML start values.
    """
    if fmi_version not in FMI_VERSIONS:
        raise ValueError(f"fmi_version must be one of {FMI_VERSIONS}, not {fmi_version!r}")
    if start_values:
        model = model.with_start_values(start_values)
    identifier = identifier or identifier_of(model.name)
    table = layout.layout(model)
    with tempfile.TemporaryDirectory(prefix="motiontwin-build-") as tmp:
        staging = Path(tmp) / "fmu"
        src = staging / "sources"
        src.mkdir(parents=True)
        runtime_files = package.copy_sources(package.runtime_sources(fmi_version), src)
        salt = fmi_version.encode() + b"".join((src / name).read_bytes() for name in runtime_files)
        token = codegen.generate(model, table, identifier, src, salt)
        c_files = sorted(f for f in [codegen.MODEL_FILE, codegen.CASADI_FILE, *runtime_files] if f.endswith(".c"))
        step = float(model.parameters[model.ts_index].start) if model.sampled else 1e-3
        xml = description.model_description(table, fmi_version=fmi_version, identifier=identifier,
                                            model_name=model.name, token=token,
                                            description=description_text or model.flat.description,
                                            step_size=step)
        if fmi_version == "2.0":
            xml = description.add_source_files(xml, c_files)
        else:
            (src / "buildDescription.xml").write_bytes(description.build_description(identifier, c_files))
        (staging / "modelDescription.xml").write_bytes(xml)
        binary_dir = staging / "binaries" / package.PLATFORM_DIR[fmi_version]
        binary_dir.mkdir(parents=True)
        package.compile_binary(src, c_files, binary_dir / f"{identifier}.so")
        folder = Path(out_dir) / ("fmi2" if fmi_version == "2.0" else "fmi3")
        path = package.pack(staging, folder / f"{identifier}.fmu")
    return BuiltFmu(path, identifier, fmi_version)


def load_model(class_name: str, modelica: Path | str = MODELICA_DIR,
               libraries: tuple[Path, ...] | None = None) -> symbolic.SymbolicModel:
    """Front end + symbolic model of one class (what identification uses too).

    ``libraries`` default: the project's Modelica library when ``modelica`` lies outside it, so that a file of
    one's own (or the ``OUT.mo`` that writeback writes) may extend ``MotionTwin.*`` classes."""
    if libraries is None:
        source, library = Path(modelica).resolve(), Path(MODELICA_DIR).resolve()
        libraries = () if source == library or library in source.parents else (Path(MODELICA_DIR),)
    return symbolic.build(frontend.load(modelica, class_name, libraries))


def exported_classes(modelica: Path | str = MODELICA_DIR) -> list[str]:
    """Full names of the classes annotated ``__motiontwin(export=true)``."""
    tree = frontend.parse_tree(Path(modelica))
    found: list[str] = []

    def walk(node: object, prefix: str) -> None:
        for name, cls in getattr(node, "classes", {}).items():
            full = f"{prefix}{name}"
            if frontend._annotation(cls).get("export") in (True, "true"):
                found.append(full)
            walk(cls, full + ".")

    walk(tree, "")
    return sorted(found)


def _build_versions(job: tuple[str, str, str, tuple[str, ...]]) -> list[BuiltFmu]:
    class_name, modelica, out_dir, versions = job
    model = load_model(class_name, modelica)
    return [build_fmu(model, out_dir, version) for version in versions]


def build(classes: list[str], modelica: Path | str = MODELICA_DIR, out_dir: Path | str = DEFAULT_OUT,
          fmi_versions: tuple[str, ...] = FMI_VERSIONS, workers: int | None = None) -> list[BuiltFmu]:
    """Build every class in ``classes`` for every FMI version, one class per process (default: all cores).

    Every class goes through the front end and the compiler in a staging folder (:func:`files.staging_folder`);
    the FMUs move into ``out_dir`` only when all of them built, so a Modelica or compiler error leaves nothing
    behind, and a move onto another file system (``out_dir`` a mount point) copies, then renames.
    """
    out_dir = Path(out_dir)
    with staging_folder(out_dir) as staging:
        jobs = [(c, str(modelica), str(staging), tuple(fmi_versions)) for c in classes]
        workers = min(workers or os.cpu_count() or 1, len(jobs))
        if workers <= 1:
            staged = [fmu for job in jobs for fmu in _build_versions(job)]
        else:
            with ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn")) as pool:
                staged = [fmu for fmus in pool.map(_build_versions, jobs) for fmu in fmus]
        built = []
        for fmu in staged:
            target = out_dir / fmu.path.relative_to(staging)
            target.parent.mkdir(parents=True, exist_ok=True)
            move_file(fmu.path, target)
            built.append(BuiltFmu(target, fmu.identifier, fmu.fmi_version))
    return built
