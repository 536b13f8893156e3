"""Test helpers: drive an FMU with fmpy's low-level classes and capture what it logs."""
from __future__ import annotations

import subprocess
import sys
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import fmpy
import numpy as np
from fmpy.fmi2 import FMU2Model, FMU2Slave, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE
from fmpy.fmi3 import FMU3Model, FMU3Slave

from motiontwin.harness.fmu_instance import extracted_fmu


GEMSEO_FMU_WHEEL = "gemseo-fmu==3.1.1"


def gemseo_fmu_folder(folder: Path) -> Path:
    """``folder`` holding the Linux FMUs of the gemseo-fmu wheel (OpenModelica-generated, third-party),
    fetched once with ``pip download gemseo-fmu --no-deps``."""
    folder.mkdir(parents=True, exist_ok=True)
    if not (folder / "add.fmu").is_file():
        subprocess.run([sys.executable, "-m", "pip", "download", GEMSEO_FMU_WHEEL, "--no-deps",
                        "--quiet", "-d", str(folder)], check=True, timeout=600)
        wheel = next(folder.glob("gemseo_fmu-*.whl"))
        prefix = "gemseo_fmu/problems/fmu_files/linux/"
        with zipfile.ZipFile(wheel) as zf:
            for name in zf.namelist():
                if name.startswith(prefix) and name.endswith(".fmu"):
                    (folder / Path(name).name).write_bytes(zf.read(name))
    return folder


@dataclass
class Loaded:
    fmu: object
    md: object
    vr: dict[str, int]
    messages: list[str] = field(default_factory=list)


def instantiate(path: Path, kind: str = "cs") -> Loaded:
    """Extract and instantiate ``path`` (kind "cs" or "me") with a logger that records messages."""
    md = fmpy.read_model_description(str(path))
    unzipdir = extracted_fmu(path)   # once per process, removed at its exit
    iface = md.coSimulation if kind == "cs" else md.modelExchange
    messages: list[str] = []
    vr = {v.name: v.valueReference for v in md.modelVariables}
    if md.fmiVersion == "2.0":
        cls = FMU2Slave if kind == "cs" else FMU2Model
        fmu = cls(guid=md.guid, unzipDirectory=unzipdir, modelIdentifier=iface.modelIdentifier,
                  instanceName="test")
        callbacks = fmi2CallbackFunctions()

        def log(env, name, status, category, message):  # noqa: ANN001 (ctypes callback)
            messages.append(message.decode())

        callbacks.logger = fmi2CallbackLoggerTYPE(log)
        callbacks.allocateMemory = fmpy.fmi2.defaultCallbacks.allocateMemory
        callbacks.freeMemory = fmpy.fmi2.defaultCallbacks.freeMemory
        fmu._keep_logger = callbacks  # keep the ctypes objects alive
        fmu.instantiate(callbacks=callbacks, loggingOn=True)
    else:
        cls = FMU3Slave if kind == "cs" else FMU3Model
        fmu = cls(guid=md.guid, unzipDirectory=unzipdir, modelIdentifier=iface.modelIdentifier,
                  instanceName="test")

        def log3(env, status, category, message):  # noqa: ANN001
            messages.append(message.decode())

        fmu.instantiate(loggingOn=True, logMessage=log3)
    return Loaded(fmu, md, vr, messages)


def get(ld: Loaded, *names: str) -> np.ndarray:
    vrs = [ld.vr[n] for n in names]
    f = ld.fmu
    return np.array(f.getReal(vrs) if ld.md.fmiVersion == "2.0" else f.getFloat64(vrs))


def set_(ld: Loaded, values: dict[str, float]) -> None:
    vrs = [ld.vr[n] for n in values]
    vals = [float(v) for v in values.values()]
    if ld.md.fmiVersion == "2.0":
        ld.fmu.setReal(vrs, vals)
    else:
        ld.fmu.setFloat64(vrs, vals)


def initialize(ld: Loaded, start: dict[str, float] | None = None, tolerance: float | None = None) -> None:
    f = ld.fmu
    if ld.md.fmiVersion == "2.0":
        f.setupExperiment(tolerance=tolerance, startTime=0.0)
    if start:
        set_(ld, start)
    f.enterInitializationMode() if ld.md.fmiVersion == "2.0" else f.enterInitializationMode(tolerance=tolerance)
    f.exitInitializationMode()


def step(ld: Loaded, t: float, h: float) -> None:
    ld.fmu.doStep(currentCommunicationPoint=t, communicationStepSize=h)


def free(ld: Loaded) -> None:
    try:
        ld.fmu.terminate()
    finally:
        ld.fmu.freeInstance()


def fmpy_closed_loop(fmu: Path, ctrl, r: np.ndarray, u_ext: np.ndarray, noise: np.ndarray,
                     values: dict[str, float], ts: float,
                     process: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """A sampled loop run by hand around the FMU (fmpy FMU2Slave) with the discrete controller ``ctrl`` on
    [r, q]: the controller reads the noisy encoder, ``process`` (a force the recording does not hold) is added
    to the plant's input; returns the recorded (q + noise, u)."""
    md = fmpy.read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    slave = FMU2Slave(guid=md.guid, unzipDirectory=extracted_fmu(fmu),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="plant")
    slave.instantiate()
    slave.setupExperiment(startTime=0.0)
    slave.enterInitializationMode()
    slave.setReal([vr[k] for k in values], list(values.values()))
    slave.exitInitializationMode()
    z = np.zeros(ctrl.n_states)
    q_rec, u_rec = np.zeros(r.size), np.zeros(r.size)
    for k in range(r.size):
        y = np.array([r[k], slave.getReal([vr["q"]])[0] + noise[k]])
        u = (ctrl.C @ z + ctrl.D @ y).item() + u_ext[k]
        z = ctrl.A @ z + ctrl.B @ y
        q_rec[k], u_rec[k] = y[1], u
        slave.setReal([vr["u"]], [u + (0.0 if process is None else process[k])])
        slave.doStep(currentCommunicationPoint=k * ts, communicationStepSize=ts)
    slave.terminate()
    slave.freeInstance()
    return q_rec, u_rec
