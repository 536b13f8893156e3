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
JUnit XML and one PNG per failing signal, and returns exit code 0 (all pass), 1 (a signal failed or
a case errored), 2 (the suite file is unusable). ``--update`` rewrites the references from the current results instead (deliberate
rebaselining).
"""

from __future__ import annotations

import re
import time as _time
import tomllib
import xml.etree.ElementTree as ET
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
                errors: dict[str, str] | None = None) -> Path:
    """JUnit XML: one testcase per (case, signal); a case that could not run is one errored testcase."""
    errors = errors or {}
    failures = sum(not r.passed for r in results)
    root = ET.Element("testsuites", name=suite, tests=str(len(results) + len(errors)),
                      failures=str(failures), errors=str(len(errors)))
    node = ET.SubElement(root, "testsuite", name=suite, tests=str(len(results) + len(errors)),
                         failures=str(failures), errors=str(len(errors)),
                         time=f"{sum(r.seconds for r in results):.6f}")
    for r in results:
        case = ET.SubElement(node, "testcase", classname=r.case, name=r.signal, time=f"{r.seconds:.6f}")
        if not r.passed:
            failure = ET.SubElement(case, "failure", message=r.message, type="ToleranceTube")
            failure.text = r.message
    for name, message in errors.items():
        case = ET.SubElement(node, "testcase", classname=name, name="run")
        error = ET.SubElement(case, "error", message=message.splitlines()[0] if message else "", type="RunError")
        error.text = message
    ET.indent(root)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_texts({path: ET.tostring(root, encoding="utf-8", xml_declaration=True)})
    return path


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name)


def plot_failure(result: SignalResult, folder: str | Path) -> Path | None:
    """PNG of the reference, tube, actual signal and violating samples of a failed comparison."""
    if result.time is None or result.reference is None:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 4.5))
    try:
        ax.plot(result.reference_time, result.reference, color="0.3", lw=1, label="reference")
        if result.lower is not None:
            ax.fill_between(result.time, result.lower, result.upper, color="tab:green", alpha=0.25, lw=0,
                            label="tolerance tube")
            outside = (result.actual < result.lower) | (result.actual > result.upper)
            ax.plot(result.time[outside], result.actual[outside], "x", color="tab:red", ms=4, label="outside")
        ax.plot(result.time, result.actual, color="tab:blue", lw=1, label="result")
        ax.set_xlabel("time [s]")
        ax.set_ylabel(result.signal)
        ax.set_title(f"{result.case}: {result.signal} FAILED", fontsize=10)
        ax.legend(loc="best", fontsize=8)
        ax.grid(True, alpha=0.3)
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


def _simulate(case: Case, root: Path) -> tuple[np.ndarray, dict[str, Any]]:
    from .master import master_for

    master = master_for(case.system)
    logs = master.run(inputs=_case_inputs(case, root), parameters=case.parameters, stop_time=case.stop_time,
                      progress=False)
    group = case.log or next(iter(logs))
    if group not in logs:
        raise SuiteError(f"case '{case.name}': no log group '{group}'; groups: {sorted(logs)}")
    return logs[group], master.metadata()


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
        parameters={n: {**f["parameters"], **{k.split(".", 1)[1]: v for k, v in case.parameters.items()
                                              if k.split(".", 1)[0] == n}} for n, f in meta["fmus"].items()},
        metadata={"regress_case": case.name},
    )
    case.reference.parent.mkdir(parents=True, exist_ok=True)
    write_recording(case.reference, rec)
    return case.reference


def run_suite(suite: str | Path, update: bool = False, junit: str | Path | None = None,
              plots: str | Path | None = None, log=print) -> int:
    """Run, compare (or ``update`` the references), write JUnit XML and plots; return the exit code."""
    from .recording import read_recording

    suite = Path(suite)
    cases = load_suite(suite)
    results: list[SignalResult] = []
    errors: dict[str, str] = {}
    for case in cases:
        try:
            actual, meta = _simulate(case, suite.parent)
            if update:
                log(f"{case.name}: reference written to {_rebaseline(case, actual, meta)}")
                continue
            reference = read_recording(case.reference)
            results.extend(compare_recordings(case.name, reference, actual, case.tolerance, case.signals))
        except Exception as exc:  # a case that cannot run is reported, the others still run
            errors[case.name] = f"{type(exc).__name__}: {exc}"
            log(f"{case.name}: ERROR {errors[case.name]}")
    if update:
        return 1 if errors else 0
    for r in results:
        log(f"{'PASS' if r.passed else 'FAIL'} {r.case} {r.signal}{': ' + r.message if r.message else ''}")
        if not r.passed and plots is not None:
            path = plot_failure(r, plots)
            if path:
                log(f"     plot: {path}")
    if junit is not None:
        write_junit(junit, results, suite=suite.stem, errors=errors)
    failed = sum(not r.passed for r in results)
    log(f"{len(results) - failed} passed, {failed} failed, {len(errors)} errors")
    return 1 if failed or errors else 0
