"""The augmented Modelica model: the nominal plant instantiated as ``plant`` plus the effects of
:mod:`ident.diagnosis.effects`, written as a self-contained source folder and loaded through the project's
front end (the expressions the fits, the FMU and every test run), for one axis (:func:`write_model`) and for
several (:func:`write_axes_structure`, each effect renamed for its axis by ``axis_prefix``).

The augmented class drives the plant's input with ``plant.<input> = u_applied - sum(F_effect)``, the library's
sign convention ``m*der(v) = u - d*v - F_effect`` (a positive effect force opposes positive motion); a sensor
effect adds its error to the measured output, ``q = plant.<output> + e``. Effects write the plant's position and
velocity as ``$x`` and ``$v``; they become the plant's own states (:class:`plant_roles.PlantRoles`).
"""
from __future__ import annotations

import shutil
import string
import tempfile
from pathlib import Path
from typing import Callable

import numpy as np

from motiontwin.fmus import frontend, symbolic
from motiontwin.fmus.build import MODELICA_DIR
from motiontwin.ident.diagnosis import axis_kinematics
from motiontwin.ident.diagnosis.bundle import PlantInfo
from motiontwin.ident.diagnosis.effect_base import Context, Effect, _decl
from motiontwin.ident.diagnosis.effects import VOCABULARY
from motiontwin.ident.diagnosis.plant_roles import PlantFormError, PlantRoles, declaration_line

LIBRARY = MODELICA_DIR / "MotionTwin"
AUGMENTED_CLASS = "Augmented"   # the class of the augmented model the diagnosis writes


def axis_prefix(axis: str) -> str:
    """The prefix of an effect's names on the axis with output ``axis`` (several axes)."""
    return f"{axis}_"


def modelica_text(plant_class: str, effects: list[Effect], values: dict[str, float],
                  plant_values: dict[str, float], class_name: str, roles: PlantRoles) -> str:
    """Source text of the augmented class (the nominal class is instantiated as ``plant``; ``roles`` name
    its input, output, position and velocity)."""
    mods = ", ".join(f"{k} = {float(v)!r}" for k, v in plant_values.items())
    names = ", ".join(e.name for e in effects) or "no effect"
    lines = [f'model {class_name} "{plant_class} augmented by the diagnosis with: {names}"',
             '  input Real u(unit = "N") "Commanded actuator force";',
             f'  output Real q(unit = "m") "Measured position (plant.{roles.output})";',
             f'  {plant_class} plant({mods}) "Nominal plant, refitted";']
    body = "".join(_decl(e.params, values) + e.declarations for e in effects)
    lines.append(body.rstrip("\n")) if body else None
    lines.append("equation")
    applied = "u - delay_a" if any(e.delays_input for e in effects) else "u"
    forces = [f"({e.force})" for e in effects if e.force]
    lines.append(f"  plant.{roles.input} = {applied}" + "".join(f" - {f}" for f in forces) + ";")
    lines.extend(f"  plant.{name} = {value!r};" for name, value in roles.held_inputs.items())
    lines.extend(f"  {eq};" for e in effects for eq in e.equations)
    sensed = "".join(f" + ({e.sensor})" for e in effects if e.sensor)
    lines.append(f"  q = plant.{roles.output}{sensed};")
    lines.append(f"end {class_name};")
    text = "\n".join(lines) + "\n"
    return string.Template(text).substitute(x=f"plant.{roles.position}", v=f"plant.{roles.velocity}")


def write_model(folder: Path, plant_text: str, plant_class: str, effects: list[Effect],
                values: dict[str, float], plant_values: dict[str, float], class_name: str,
                roles: PlantRoles) -> Path:
    """Write a self-contained Modelica folder (nominal plant, augmented class, library functions used)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "plant.mo").write_text(plant_text, encoding="utf-8")
    path = folder / f"{class_name}.mo"
    path.write_text(modelica_text(plant_class, effects, values, plant_values, class_name, roles),
                    encoding="utf-8")
    used = sorted({f for e in effects for f in e.library})
    if used:
        lib = folder / "MotionTwin"
        (lib / "Effects").mkdir(parents=True, exist_ok=True)
        shutil.copyfile(LIBRARY / "package.mo", lib / "package.mo")
        shutil.copyfile(LIBRARY / "Effects" / "package.mo", lib / "Effects" / "package.mo")
        for name in used:
            shutil.copyfile(LIBRARY / "Effects" / name, lib / "Effects" / name)
    return path


def check_buildable(folder: Path, plant_text: str, plant_path: Path, plant_class: str, roles: PlantRoles,
                    ctx: Context, class_name: str) -> symbolic.SymbolicModel:
    """Build the augmented model of every catalogue effect through the front end before any fitting, so
    that an unsupported plant form stops the diagnosis at once with one message.

    All effects go into one model (one front-end pass); only when it fails is each effect built alone to
    name the one at fault. Raises :class:`plant_roles.PlantFormError` naming the effect, the construct and
    the line of ``plant_path``.

    Parameters
    ----------
    folder : empty scratch folder for the written models.
    plant_text, plant_path, plant_class : the plant file's source, path and the class used.
    roles : where the plant keeps its input, output, position and velocity.
    ctx : recorded ranges (for the effects' parameter bounds).
    class_name : name of the augmented class.

    Returns
    -------
    SymbolicModel
        The augmented model with every effect (written to ``folder / "all"``).
    """
    top = plant_class.split(".")[0]
    if top in (class_name, LIBRARY.name):
        raise PlantFormError(f"{plant_path}, line {declaration_line(plant_text, top)}: the plant's top-level "
                             f"class name {top!r} clashes with the diagnosis' own {class_name!r} or "
                             f"{LIBRARY.name!r}; rename it")
    effects = [factory(ctx) for factory in VOCABULARY.values()]

    def build(chosen: list[Effect], sub: str) -> symbolic.SymbolicModel:
        values = {p.name: float(np.mean(p.bounds)) for e in chosen for p in e.params}
        model = load_written(lambda where, written: write_model(where, plant_text, plant_class, chosen, written, {},
                                                                class_name, roles),
                             lambda where: load_augmented(where, class_name), values, folder / sub)
        states = {s.name for s in model.states}
        missing = [f"plant.{n}" for n in (roles.position, roles.velocity) if f"plant.{n}" not in states]
        if missing:
            raise PlantFormError(f"{', '.join(missing)} is not a state of the augmented model")
        return model

    try:
        return build(effects, "all")
    except (frontend.ModelicaError, PlantFormError, RuntimeError, ValueError, KeyError):
        pass
    for effect in effects:
        try:
            build([effect], effect.name)
        except (frontend.ModelicaError, PlantFormError, RuntimeError, ValueError, KeyError) as exc:
            source = " ".join([effect.force, effect.sensor, *effect.equations])
            used = [roles.input] + [name for token, name in (("$x", roles.position), ("$v", roles.velocity))
                                    if token in source]
            construct = ", ".join(f"plant.{name}" for name in used)
            line = declaration_line(plant_text, plant_class)
            raise PlantFormError(f"{plant_path}, line {line}: class {plant_class}: the augmented model with "
                                 f"effect {effect.name} (which uses {construct}) cannot be built, so this plant "
                                 f"form is not supported: {exc}") from None
    raise PlantFormError(f"{plant_path}, line {declaration_line(plant_text, plant_class)}: class {plant_class}: "
                         f"the augmented model with all effects cannot be built although each effect alone can")


def load_augmented(folder: Path, class_name: str) -> symbolic.SymbolicModel:
    """The augmented model through the project's front end (the same expressions the FMU runs)."""
    return symbolic.build(frontend.load(folder, class_name))


#: the value every parameter is written with in the source a structure is loaded from (:func:`load_written`)
CANONICAL_VALUE = 1.0


def load_written(write: Callable[[Path, dict[str, float]], object], load: Callable[[Path], symbolic.SymbolicModel],
                 values: dict[str, float], folder: Path) -> symbolic.SymbolicModel:
    """The model that ``write(folder, values)`` writes and ``load(folder)`` reads, loaded from the same source
    written with every value at ``CANONICAL_VALUE`` (in a temporary folder beside ``folder``: inside the
    diagnosis' own work folder, which its cleanup removes even when a worker is killed), then given the written
    values as its parameters' start values (a value written into the text comes back exactly, ``float`` repr),
    and ``folder`` as its source. Why: the front end caches a flattened model by its source text
    (:mod:`fmus.modelcache`), and a structure's text changes only by its values from one fit, candidate or
    diagnosis to the next; loaded so,
    each structure is parsed and flattened once per machine and plant file, not once per diagnosis (24 parses,
    about a quarter of the CPU of a 1.5 s + 0.75 s single-axis diagnosis). The writers put a value into the text
    as a modifier of the plant (``plant.`` names) or as an effect's parameter; a plant modifier that sets no
    parameter, or a canonical source that does not load, makes the model read from the written folder instead
    (its errors name it)."""
    write(folder, values)
    try:
        with tempfile.TemporaryDirectory(prefix=".canonical-", dir=folder.parent) as tmp:
            write(Path(tmp), dict.fromkeys(values, CANONICAL_VALUE))
            model = load(Path(tmp))
    except frontend.ModelicaError:
        return load(folder)
    parameters = {v.name: v for v in model.parameters}
    if any(name.startswith("plant.") and name not in parameters for name in values):
        return load(folder)
    for name, value in values.items():
        if name in parameters:
            parameters[name].start = float(value)
    model.flat.source = folder
    return model


def write_structure(plant: PlantInfo, effects: list[Effect], values: dict[str, float], folder: Path) -> Path:
    """Write the self-contained Modelica folder of the nominal ``plant`` + ``effects`` at ``values`` (one axis;
    several: :func:`write_axes_structure`)."""
    plant_values = {k[len("plant."):]: v for k, v in values.items() if k.startswith("plant.")}
    return write_model(folder, plant.text, plant.class_name, effects, values, plant_values, AUGMENTED_CLASS,
                       plant.roles)


def axes_modelica_text(plant: PlantInfo, effects: list[tuple[str, Effect]], values: dict[str, float],
                  plant_values: dict[str, float]) -> str:
    """Source of the augmented class: the nominal class as ``plant``, one input and output per axis (the
    plant's own names), every effect's force subtracted from its axis's input."""
    mods = ", ".join(f"{k} = {float(v)!r}" for k, v in plant_values.items())
    listed = ", ".join(f"{e.name} on {axis}" for axis, e in effects) or "no effect"
    lines = [f'model {AUGMENTED_CLASS} "{plant.class_name} augmented by the diagnosis with: {listed}"']
    lines += [f'  input Real {a.input}(unit = "N") "Commanded force of axis {a.output}";' for a in plant.axes]
    lines += [f'  output Real {a.output}(unit = "m") "Measured position of axis {a.output}";' for a in plant.axes]
    lines.append(f'  {plant.class_name} plant({mods}) "Nominal plant, refitted";')
    body = "".join(_decl(e.params, values) + e.declarations for _, e in effects)
    if body:
        lines.append(body.rstrip("\n"))
    lines.append("equation")
    for a in plant.axes:
        mine = [e for axis, e in effects if axis == a.output]
        delay = next((e for e in mine if e.delays_input), None)
        applied = f"{a.input} - {axis_prefix(a.output)}delay_a" if delay else a.input
        forces = "".join(f" - ({e.force})" for e in mine if e.force)
        lines.append(f"  plant.{a.input} = {applied}{forces};")
    lines.extend(f"  plant.{name} = {value!r};" for name, value in plant.axes[0].held_inputs.items())
    lines.extend(f"  {eq};" for _, e in effects for eq in e.equations)
    for a in plant.axes:
        sensed = "".join(f" + ({e.sensor})" for axis, e in effects if axis == a.output and e.sensor)
        lines.append(f"  {a.output} = plant.{a.output}{sensed};")
    lines.append(f"end {AUGMENTED_CLASS};")
    return "\n".join(lines) + "\n"


def write_axes_structure(plant: PlantInfo, effects: list[tuple[str, Effect]],
                         values: dict[str, float], folder: Path) -> Path:
    """Write the plant file, the augmented class and the position/velocity functions of expression axes into
    ``folder`` (the MotionTwin library is loaded from the project's Modelica folder, so a library plant may
    use other library classes)."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "plant.mo").write_text(plant.text, encoding="utf-8")
    for name, text in axis_kinematics.function_files(plant.model, plant.axes).items():
        (folder / name).write_text(text, encoding="utf-8")
    plant_values = {k[len("plant."):]: v for k, v in values.items() if k.startswith("plant.")}
    path = folder / f"{AUGMENTED_CLASS}.mo"
    path.write_text(axes_modelica_text(plant, effects, values, plant_values), encoding="utf-8")
    return path


def load_structure(folder: Path) -> symbolic.SymbolicModel:
    """The augmented model written by :func:`write_axes_structure`, through the project's front end."""
    return symbolic.build(frontend.load(folder, AUGMENTED_CLASS, (MODELICA_DIR,)))
