"""FMU regression checks for CI: tolerance tubes around reference recordings, JUnit XML, plots, exit code.

Tube (as the Modelica Association's csv-compare does it, with explicit bounds): around the reference
polyline ``y_ref(t)`` every reference point is widened to a rectangle of half-width ``time_shift``
(s) and half-height ``delta = max(abs, rel * max|y_ref|)`` (signal units). The tube is the envelope of
these rectangles: ``lower(t) = min y_ref(s) - delta`` and ``upper(t) = max y_ref(s) + delta`` over
``|s - t| <= time_shift``. A signal passes when every sample of the actual result inside the
reference's time range lies in the tube, the actual time range covers the reference's, and no value
is NaN. The time widening lets a step or an event move by up to ``time_shift`` without failing, while
away from fast changes the tube stays ``delta`` wide.

Suite file (TOML), paths relative to it::

    [tolerance]                  # suite defaults (a case may override any of them)
    abs = 1e-9                   # signal units
    rel = 1e-3                   # fraction of the reference's peak magnitude
    time_shift = 1e-4            # s

    [[case]]
    name = "p_loop_step"
    system = "loop.toml"         # a harness system file
    reference = "refs/p_loop_step.csv"   # recording CSV + JSON sidecar (harness.recording)
    stop_time = 0.2              # optional, default: the system's stop_time
    log = "log"                  # optional log group to compare, default: the first
    signals = ["plant.y"]        # optional, default: every logged signal
    [case.inputs]                # the system's external inputs (harness.inputs): constants, a recording
    r = -0.4                     # column or an experiment signal (held from sample to sample), paths
    u_ext = {recording = "excitation/sweep.csv", column = "u_ext"}   # relative to the suite file
    [case.parameters]            # per-run overrides "inst.variable" = value
    "ctrl.add.k1" = 5000.0

``motiontwin regress SUITE [--update] [--junit FILE] [--plots DIR]`` runs every case, compares, writes
JUnit XML and one PNG per failing signal (signal and tube with units above, the residual against the tube
below; the failure message names the file), and returns exit code 0 (all pass), 1 (a signal failed or a
case errored, e.g. a missing reference), 2 (the suite file is unusable: missing, not TOML, a bad field;
the JUnit XML then holds one ``<error>``). ``--update`` rewrites the references from the current results
instead (deliberate rebaselining; with ``--junit`` one passed testcase per case). A reference records every
FMU's content sha256 (:func:`fmu_sha256`) and its effective parameters (start values and overrides); a run whose FMUs or parameters
differ from the reference's says so on the console and in the JUnit ``<system-out>``.

JUnit XML (the Ant/Jenkins schema CI servers read): ``<testsuites>`` holding one ``<testsuite>`` with
``name``, ``id``, ``package``, ``tests``, ``failures``, ``errors``, ``time``, ``timestamp`` and ``hostname``,
then ``<properties>`` (the FMUs' sha256), one ``<testcase classname=CASE name=SIGNAL time=...>`` per
signal, ``<system-out>`` and ``<system-err>``. A testcase's time is its share of the whole case: the
simulation split evenly over the case's signals plus its own comparison.
"""

from __future__ import annotations

import hashlib
import re
import socket
import sys
import time as _time
import tomllib
import xml.etree.ElementTree as ET
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np

from motiontwin.harness.numbers import is_finite_number
from motiontwin.harness.recording import atomic_write_texts, write_figure


@dataclass(frozen=True)
class Tolerance:
    """Tube bounds: ``abs`` and ``rel`` (fraction of peak |reference|) in y, ``time_shift`` in s."""

    abs: float = 1e-9
    rel: float = 1e-3
    time_shift: float = 0.0


@dataclass
class SignalResult:
    """Outcome of comparing one signal against its tube."""

    case: str
    signal: str
    passed: bool
    message: str = ""
    max_excess: float = 0.0
    first_failure_time: float | None = None
    violations: int = 0
    time: np.ndarray | None = field(default=None, repr=False)
    actual: np.ndarray | None = field(default=None, repr=False)
    lower: np.ndarray | None = field(default=None, repr=False)
    upper: np.ndarray | None = field(default=None, repr=False)
    reference_time: np.ndarray | None = field(default=None, repr=False)
    reference: np.ndarray | None = field(default=None, repr=False)
    seconds: float = 0.0
    unit: str = ""
    notes: list[str] = field(default_factory=list)


def _window_extremes(t_ref: np.ndarray, y_ref: np.ndarray, t: np.ndarray, shift: float) -> tuple[np.ndarray, np.ndarray]:
    """min and max of the reference polyline over [t - shift, t + shift] for every t."""
    left, right = t - shift, t + shift
    y_left = np.interp(left, t_ref, y_ref)
    y_right = np.interp(right, t_ref, y_ref)
    lo = np.minimum(y_left, y_right)
    hi = np.maximum(y_left, y_right)
    start = np.searchsorted(t_ref, left, side="left")
    stop = np.searchsorted(t_ref, right, side="right")
    inside = stop > start  # windows that contain reference vertices
    if np.any(inside):
        padded = np.append(y_ref, y_ref[-1])
        bounds = np.column_stack([start[inside], stop[inside]]).ravel()
        lo[inside] = np.minimum(lo[inside], np.minimum.reduceat(padded, bounds)[::2])
        hi[inside] = np.maximum(hi[inside], np.maximum.reduceat(padded, bounds)[::2])
    return lo, hi


def tube(t_ref: np.ndarray, y_ref: np.ndarray, t: np.ndarray, tolerance: Tolerance) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper tube bounds around the reference, evaluated at the times ``t``."""
    t_ref = np.asarray(t_ref, float)
    y_ref = np.asarray(y_ref, float)
    delta = max(tolerance.abs, tolerance.rel * float(np.max(np.abs(y_ref))) if y_ref.size else 0.0)
    lo, hi = _window_extremes(t_ref, y_ref, np.asarray(t, float), tolerance.time_shift)
    return lo - delta, hi + delta


def compare_signal(case: str, signal: str, t_ref: Sequence[float], y_ref: Sequence[float],
                   t: Sequence[float], y: Sequence[float], tolerance: Tolerance) -> SignalResult:
    """Check the actual signal (t, y) against the tube around the reference (t_ref, y_ref)."""
    t0 = _time.perf_counter()
    t_ref, y_ref, t, y = (np.asarray(a, float) for a in (t_ref, y_ref, t, y))
    result = SignalResult(case, signal, True, time=t, actual=y, reference_time=t_ref, reference=y_ref)
    eps = 1e-9 * max(1.0, abs(float(t_ref[-1])))
    if t[0] > t_ref[0] + eps or t[-1] < t_ref[-1] - eps:
        result.passed = False
        result.message = (f"time range [{t[0]:g}, {t[-1]:g}] s does not cover the reference's "
                          f"[{t_ref[0]:g}, {t_ref[-1]:g}] s")
        return result
    if not np.all(np.isfinite(y)):
        i = int(np.flatnonzero(~np.isfinite(y))[0])
        result.passed = False
        result.first_failure_time = float(t[i])
        result.message = f"non-finite value {y[i]} at t = {t[i]:.9g} s"
        return result
    within = (t >= t_ref[0] - eps) & (t <= t_ref[-1] + eps)
    lower = np.full_like(y, np.nan)
    upper = np.full_like(y, np.nan)
    lower[within], upper[within] = tube(t_ref, y_ref, t[within], tolerance)
    excess = np.where(within, np.maximum(lower - y, y - upper), -np.inf)
    bad = np.flatnonzero(excess > 0)
    result.lower, result.upper = lower, upper
    result.seconds = _time.perf_counter() - t0
    if bad.size:
        i = int(bad[0])
        result.passed = False
        result.violations = int(bad.size)
        result.max_excess = float(excess[bad].max())
        result.first_failure_time = float(t[i])
        result.message = (f"{bad.size} of {int(within.sum())} samples outside the tube (abs {tolerance.abs:g}, "
                          f"rel {tolerance.rel:g}, time shift {tolerance.time_shift:g} s); first at "
                          f"t = {t[i]:.9g} s: {y[i]:.9g} not in [{lower[i]:.9g}, {upper[i]:.9g}]; "
                          f"largest excess {result.max_excess:.3g}")
    return result


def compare_recordings(case: str, reference: Any, actual: Any, tolerance: Tolerance,
                       signals: Iterable[str] | None = None) -> list[SignalResult]:
    """Compare every signal of ``reference`` (a harness.recording.Recording or a structured array
    with a ``time`` field) with the same-named signal of ``actual`` (either kind)."""
    ref_t, ref_cols = _columns(reference)
    act_t, act_cols = _columns(actual)
    units = getattr(reference, "units", {})
    names = list(signals) if signals is not None else list(ref_cols)
    results = []
    for name in names:
        if name not in ref_cols:
            results.append(SignalResult(case, name, False, f"signal {name!r} missing from the reference"))
        elif name not in act_cols:
            results.append(SignalResult(case, name, False, f"signal {name!r} missing from the result; "
                                                           f"result has {sorted(act_cols)}"))
        else:
            results.append(compare_signal(case, name, ref_t, ref_cols[name], act_t, act_cols[name], tolerance))
            results[-1].unit = units.get(name) or ""
    return results


def _columns(data: Any) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    if isinstance(data, np.ndarray) and data.dtype.names:
        return data["time"], {n: data[n] for n in data.dtype.names if n != "time"}
    if hasattr(data, "time") and hasattr(data, "columns"):
        return np.asarray(data.time), dict(data.columns)
    if isinstance(data, dict) and "time" in data:
        return np.asarray(data["time"]), {k: np.asarray(v) for k, v in data.items() if k != "time"}
    raise TypeError(f"cannot read signals from {type(data).__name__}")


# ---------------------------------------------------------------------------------------------
# outputs


def write_junit(path: str | Path, results: Sequence[SignalResult], suite: str = "motiontwin-regress",
                errors: dict[str, str] | None = None, error_seconds: dict[str, float] | None = None,
                properties: dict[str, str] | None = None, seconds: float | None = None) -> Path:
    """JUnit XML (Ant/Jenkins schema, see the module docstring): one testcase per (case, signal); a case that
    could not run, or an unusable suite file, is one testcase named "run" holding an ``<error>``
    (``errors``: classname -> "Type: message"). ``seconds``: the suite's wall time (default: the sum)."""
    errors, error_seconds = errors or {}, error_seconds or {}
    failures = sum(not r.passed for r in results)
    total = sum(r.seconds for r in results) + sum(error_seconds.values()) if seconds is None else seconds
    root = ET.Element("testsuites")
    node = ET.SubElement(root, "testsuite", name=suite, id="0", package=suite, tests=str(len(results) + len(errors)),
                         failures=str(failures), errors=str(len(errors)), time=f"{total:.3f}",
                         timestamp=_time.strftime("%Y-%m-%dT%H:%M:%S"), hostname=socket.gethostname() or "localhost")
    props = ET.SubElement(node, "properties")
    for name, value in (properties or {}).items():
        ET.SubElement(props, "property", name=name, value=value)
    out = []
    for r in results:
        case = ET.SubElement(node, "testcase", classname=r.case, name=r.signal, time=f"{r.seconds:.3f}")
        if not r.passed:
            failure = ET.SubElement(case, "failure", message=r.message, type="ToleranceTube")
            failure.text = "\n".join([r.message, *r.notes])
        out.extend(f"{r.case}: {n}" for n in r.notes)
    for name, message in errors.items():
        case = ET.SubElement(node, "testcase", classname=name, name="run", time=f"{error_seconds.get(name, 0.0):.3f}")
        kind = message.split(":", 1)[0] if ":" in message else "RunError"
        error = ET.SubElement(case, "error", message=message.splitlines()[0] if message else "", type=kind)
        error.text = message
    ET.SubElement(node, "system-out").text = "\n".join(dict.fromkeys(out))
    ET.SubElement(node, "system-err").text = "\n".join(errors.values())
    ET.indent(root)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_texts({path: ET.tostring(root, encoding="utf-8", xml_declaration=True)})
    return path


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name)


def plot_failure(result: SignalResult, folder: str | Path) -> Path | None:
    """PNG of a failed comparison: reference, tube and result in the signal's unit above; below, the
    residual (result - reference at the result's instants) inside the tube's band, violations marked."""
    if result.time is None or result.reference is None:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    unit = f" [{result.unit}]" if result.unit else " (no unit declared)"
    fig, (ax, res) = plt.subplots(2, 1, figsize=(9, 6.5), sharex=True, height_ratios=(3, 2))
    try:
        ax.plot(result.reference_time, result.reference, color="0.3", lw=1, label="reference")
        ref = np.interp(result.time, result.reference_time, result.reference)
        res.axhline(0.0, color="0.3", lw=1)
        if result.lower is not None:
            outside = (result.actual < result.lower) | (result.actual > result.upper)
            ax.fill_between(result.time, result.lower, result.upper, color="tab:green", alpha=0.25, lw=0,
                            label="tolerance tube")
            ax.plot(result.time[outside], result.actual[outside], "x", color="tab:red", ms=4, label="outside")
            res.fill_between(result.time, result.lower - ref, result.upper - ref, color="tab:green", alpha=0.25,
                             lw=0, label="tube - reference")
            res.plot(result.time[outside], (result.actual - ref)[outside], "x", color="tab:red", ms=4)
        ax.plot(result.time, result.actual, color="tab:blue", lw=1, label="result")
        res.plot(result.time, result.actual - ref, color="tab:blue", lw=1, label="result - reference")
        ax.set_ylabel(f"{result.signal}{unit}")
        res.set_ylabel(f"residual{unit}")
        res.set_xlabel("time [s]")
        ax.set_title(f"{result.case}: {result.signal} FAILED", fontsize=10)
        for a in (ax, res):
            a.legend(loc="best", fontsize=8)
            a.grid(True, alpha=0.3)
        fig.tight_layout()
        path = Path(folder) / f"{_safe(result.case)}__{_safe(result.signal)}.png"
        write_figure(path, fig, dpi=100)
    finally:
        plt.close(fig)
    return path


# ---------------------------------------------------------------------------------------------
# suites


class SuiteError(ValueError):
    """The suite file is malformed (message names file and field)."""


@dataclass
class Case:
    name: str
    system: Path
    reference: Path
    tolerance: Tolerance
    stop_time: float | None = None
    log: str | None = None
    signals: tuple[str, ...] | None = None
    inputs: dict[str, float] = field(default_factory=dict)
    parameters: dict[str, Any] = field(default_factory=dict)


def _tolerance(table: dict, base: Tolerance, where: str) -> Tolerance:
    unknown = set(table) - {"abs", "rel", "time_shift"}
    if unknown:
        raise SuiteError(f"{where}: unknown tolerance field(s) {sorted(unknown)}; allowed: abs, rel, time_shift")
    values = {}
    for key in ("abs", "rel", "time_shift"):
        value = table.get(key, getattr(base, key))
        if not is_finite_number(value) or value < 0:
            raise SuiteError(f"{where}: tolerance {key} must be a number >= 0, got {value!r}")
        values[key] = float(value)
    return Tolerance(**values)


def load_suite(path: str | Path) -> list[Case]:
    """Read a suite file (see the module docstring)."""
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise SuiteError(f"{path}: cannot read the suite file ({exc.strerror or exc})") from None
    except UnicodeDecodeError as exc:
        raise SuiteError(f"{path}: not UTF-8 text (byte {exc.start}: {exc.reason})") from None
    except tomllib.TOMLDecodeError as exc:
        raise SuiteError(f"{path}: {exc}") from None
    default = _tolerance(data.get("tolerance", {}), Tolerance(), f"{path}: [tolerance]")
    cases = []
    for index, table in enumerate(data.get("case", [])):
        where = f"{path}: [[case]] #{index + 1}"
        for key in ("name", "system", "reference"):
            if not isinstance(table.get(key), str):
                raise SuiteError(f"{where}: missing field '{key}' (string)")
        where = f"{path}: [[case]] '{table['name']}'"
        unknown = set(table) - {"name", "system", "reference", "stop_time", "log", "signals", "inputs",
                                "parameters", "tolerance"}
        if unknown:
            raise SuiteError(f"{where}: unknown field(s) {sorted(unknown)}")
        signals = table.get("signals")
        cases.append(Case(
            name=table["name"],
            system=(path.parent / table["system"]),
            reference=(path.parent / table["reference"]),
            tolerance=_tolerance(table.get("tolerance", {}), default, where),
            stop_time=table.get("stop_time"),
            log=table.get("log"),
            signals=tuple(signals) if signals is not None else None,
            inputs=dict(table.get("inputs", {})),
            parameters=dict(table.get("parameters", {})),
        ))
    if not cases:
        raise SuiteError(f"{path}: no [[case]] tables")
    if len({c.name for c in cases}) != len(cases):
        raise SuiteError(f"{path}: case names must be unique")
    return cases


def _case_inputs(case: Case, root: Path) -> dict[str, Any]:
    from .inputs import resolve_input

    return {name: resolve_input(value, root, f"case '{case.name}': input '{name}'")
            for name, value in case.inputs.items()}


def fmu_sha256(path: str | Path) -> str:
    """sha256 of an FMU's contents: every member's name and bytes in name order, modelDescription.xml without
    its generationDateAndTime (zip timestamps and the generation time change with every rebuild of the same
    FMU; the hash should not)."""
    digest = hashlib.sha256()
    with zipfile.ZipFile(path) as zf:
        for name in sorted(zf.namelist()):
            data = zf.read(name)
            if name == "modelDescription.xml":
                data = re.sub(rb'\sgenerationDateAndTime="[^"]*"', b"", data)
            digest.update(name.encode() + b"\0" + len(data).to_bytes(8, "little") + data)
    return digest.hexdigest()


def _simulate(case: Case, root: Path) -> tuple[np.ndarray, dict[str, Any]]:
    """Run the case; its log group and the system's metadata with, per FMU, ``sha256`` and the effective
    ``parameters`` (modelDescription start values, then the system file's and the case's overrides)."""
    from .master import master_for

    master = master_for(case.system)
    logs = master.run(inputs=_case_inputs(case, root), parameters=case.parameters, stop_time=case.stop_time,
                      progress=False)
    group = case.log or next(iter(logs))
    if group not in logs:
        raise SuiteError(f"case '{case.name}': no log group '{group}'; groups: {sorted(logs)}")
    meta = master.metadata()
    for name, fmu in meta["fmus"].items():
        starts = {v.name: float(v.start) for v in master.instances[name].model_description.modelVariables
                  if v.causality == "parameter" and v.type in ("Real", "Float64") and v.start is not None}
        case_values = {k.split(".", 1)[1]: v for k, v in case.parameters.items() if k.split(".", 1)[0] == name}
        fmu["parameters"] = {**starts, **fmu["parameters"], **case_values}
        fmu["sha256"] = fmu_sha256(fmu["path"])
    return logs[group], meta


def _rebaseline(case: Case, log: np.ndarray, meta: dict[str, Any]) -> Path:
    from .recording import make_recording, write_recording

    names = [n for n in log.dtype.names if n != "time" and (case.signals is None or n in case.signals)]
    units = {n: (meta["units"].get(n) or "") for n in names}
    step = np.diff(log["time"])
    rec = make_recording(
        log["time"], {n: log[n] for n in names}, {"time": "s", **units},
        sample_time=float(step[0]) if step.size and np.allclose(step, step[0]) else None,
        excited={"inputs": case.inputs},
        fmus=meta["fmus"],
        parameters={n: f["parameters"] for n, f in meta["fmus"].items()},
        metadata={"regress_case": case.name},
    )
    case.reference.parent.mkdir(parents=True, exist_ok=True)
    write_recording(case.reference, rec)
    return case.reference


def _differences(reference: Any, meta: dict[str, Any]) -> list[str]:
    """What changed since the reference was recorded: an FMU's sha256, a parameter value."""
    notes = []
    ref_fmus = reference.meta.get("fmus") or {}
    for name, fmu in meta["fmus"].items():
        ref = ref_fmus.get(name) if isinstance(ref_fmus, dict) else None
        if not isinstance(ref, dict) or "sha256" not in ref:
            notes.append(f"FMU '{name}': the reference records no sha256 (rebaseline with --update to record it)")
            continue
        if ref["sha256"] != fmu["sha256"]:
            notes.append(f"FMU '{name}' differs from the reference's: sha256 {fmu['sha256'][:12]}..., reference "
                         f"{ref['sha256'][:12]}... ({fmu['path']})")
        ref_pars = (reference.meta.get("parameters") or {}).get(name) or {}
        changed = sorted(k for k in set(ref_pars) | set(fmu["parameters"])
                         if ref_pars.get(k) != fmu["parameters"].get(k))
        if changed:
            notes.append(f"FMU '{name}': parameters differ from the reference's: " + ", ".join(
                f"{k} = {fmu['parameters'].get(k)} (reference {ref_pars.get(k)})" for k in changed))
    return notes


def _run_case(case: Case, suite: Path, update: bool, log, hashes: dict[str, str]) -> list[SignalResult]:
    """Simulate and compare (or rebaseline) one case; the results carry the whole case's time. Adds the
    FMUs' sha256 to ``hashes`` (property name "sha256 PATH")."""
    from .recording import read_recording

    start = _time.perf_counter()
    if not update and not case.reference.is_file():
        raise FileNotFoundError(f"reference {case.reference} not found: run `motiontwin regress {suite} --update` "
                                f"to record it")
    actual, meta = _simulate(case, suite.parent)
    simulated = _time.perf_counter() - start
    hashes.update({f"sha256 {fmu['path']}": fmu["sha256"] for fmu in meta["fmus"].values()})
    if update:
        path = _rebaseline(case, actual, meta)
        log(f"{case.name}: reference written to {path}")
        return [SignalResult(case.name, "update", True, f"reference written to {path}",
                             seconds=_time.perf_counter() - start)]
    reference = read_recording(case.reference)
    results = compare_recordings(case.name, reference, actual, case.tolerance, case.signals)
    notes = _differences(reference, meta)
    for note in notes:
        log(f"{case.name}: NOTE {note}")
    for r in results:
        r.seconds += simulated / len(results)
        r.notes = list(notes)
    return results


def _print_error(message: str) -> None:
    print(message, file=sys.stderr)


def run_suite(suite: str | Path, update: bool = False, junit: str | Path | None = None,
              plots: str | Path | None = None, log=print, error=_print_error) -> int:
    """Run, compare (or ``update`` the references), write JUnit XML and plots; return the exit code
    (0 all passed, 1 a failure or a case error, 2 an unusable suite file, reported through ``error``)."""
    suite = Path(suite)
    start = _time.perf_counter()
    try:
        cases = load_suite(suite)
    except SuiteError as exc:
        error(f"motiontwin regress: {exc}")
        if junit is not None:
            write_junit(junit, [], suite=suite.stem, errors={str(suite): f"SuiteError: {exc}"})
        return 2
    results: list[SignalResult] = []
    errors: dict[str, str] = {}
    error_seconds: dict[str, float] = {}
    hashes: dict[str, str] = {}
    for case in cases:
        case_start = _time.perf_counter()
        try:
            results.extend(_run_case(case, suite, update, log, hashes))
        except Exception as exc:  # a case that cannot run is reported, the others still run
            errors[case.name] = f"{type(exc).__name__}: {exc}"
            error_seconds[case.name] = _time.perf_counter() - case_start
            log(f"{case.name}: ERROR {errors[case.name]}")
    for r in results:
        if not r.passed and plots is not None:
            path = plot_failure(r, plots)
            if path:
                r.message += f"; plot: {path}"
        if not update:
            log(f"{'PASS' if r.passed else 'FAIL'} {r.case} {r.signal}{': ' + r.message if r.message else ''}")
    if junit is not None:
        write_junit(junit, results, suite=suite.stem, errors=errors, error_seconds=error_seconds,
                    properties=hashes, seconds=_time.perf_counter() - start)
    failed = sum(not r.passed for r in results)
    log(f"{len(results) - failed} {'updated' if update else 'passed'}, {failed} failed, {len(errors)} errors")
    return 1 if failed or errors else 0
