"""The paper's Table 2 designs beside a tuned one, on our plant.

Table 2 comparison: the paper's gains are in its own (unknown) units, so on an SI plant only the controller
shape is comparable; Kp, Ki, Kd are scaled by one factor g chosen so that the CLBW on our plant equals the
paper's CLBW for that column, and the GM, PM, max |S| reached are printed beside the paper's.

Units: SI. Plant K in m/(N s^2) (1/mass), alpha and omega in rad/s; controller gains in N/m, N/(m s), N s/m;
controller frequencies fc, fp, wl, wh in Hz (as in Table 2 and the FMU); Ts in s; margins in dB and deg;
bandwidth in Hz; tau_cl and tau_max in s.
"""
from __future__ import annotations

import math

import control
import numpy as np
import scipy.optimize

from motiontwin.ident.frf import JointModel
from motiontwin.ident.tuning.margins import _LoopEvaluator, controller_defaults, loop_margins
from motiontwin.ident.tuning.spec import DESIGN_NAMES, TuningError, TuningResult

__all__ = ["TABLE2", "TABLE2_READINGS", "rescale_to_bandwidth", "table2_parameters", "table2_comparison",
           "format_comparison", "comparison_markdown"]


# Cheung & Hung Table 2 (gains in the paper's own units; fp, fc, wl = omega_r, wh = omega_b in Hz) and the
# paper's figures GM [dB], PM [deg], CLBW [Hz], S (max |S| below CLBW).
TABLE2: dict[str, dict[str, float]] = {
    "d1": dict(Kp=0.7987, Ki=0.003, Kd=15.1038, Kv=4.8751, Ka=60.411, KL=10, fp=305, fc=533, wl=380, wh=400,
               sigma=15, GM=8.01, PM=50, CLBW=69.6, S=0.98),
    "d3": dict(Kp=0.7229, Ki=0.001, Kd=12.8725, Kv=5.5518, Ka=32.757, KL=10, fp=316, fc=716, wl=446, wh=300,
               sigma=25, GM=8.02, PM=50, CLBW=73.4, S=0.85),
    "d5": dict(Kp=0.9122, Ki=0.0005, Kd=13.1532, Kv=2.8185, Ka=31.04, KL=10, fp=320, fc=690, wl=355, wh=400,
               sigma=15, GM=8.69, PM=49.3, CLBW=59.3, S=0.94),
    "d7": dict(Kp=0.8438, Ki=0.01, Kd=15.4567, Kv=9.6264, Ka=49.411, KL=10, fp=305, fc=617, wl=370, wh=300,
               sigma=30, GM=8.55, PM=60, CLBW=56.1, S=0.7),
}

_PAPER_FIGURES = ("GM", "PM", "CLBW", "S")


def rescale_to_bandwidth(parameters: dict[str, float], plant: JointModel | control.LTI, target_hz: float,
                         delay_samples: int = 1) -> tuple[dict[str, float], float]:
    """Scale Kp, Ki, Kd by one factor g (the controller's shape unchanged) so that the closed-loop bandwidth
    on ``plant`` equals ``target_hz``; returns (scaled parameters, g). Why: Table 2 gains are in the paper's
    own (unknown) units, so only their shape is comparable on an SI plant; the paper's own CLBW fixes g."""
    ts = float(parameters.get("Ts", controller_defaults()["Ts"]))
    evaluator = _LoopEvaluator([plant], ts, delay_samples)

    def scaled(log_g: float) -> dict[str, float]:
        g = 10 ** log_g
        return {**parameters, "Kp": parameters["Kp"] * g, "Ki": parameters["Ki"] * g, "Kd": parameters["Kd"] * g}

    def bw_error(log_g: float) -> float:
        m = evaluator.evaluate(scaled(log_g))[0]
        return math.log(max(m.bandwidth_hz, 1e-3) / target_hz) if m.stable else math.inf

    grid = np.linspace(-3, 9, 241)
    errors = np.array([bw_error(g) for g in grid])
    sign = np.nonzero(np.isfinite(errors[:-1]) & np.isfinite(errors[1:]) & (errors[:-1] < 0) & (errors[1:] >= 0))[0]
    if not sign.size:
        raise TuningError(f"no stable scaling of Kp, Ki, Kd reaches a closed-loop bandwidth of {target_hz} Hz")
    log_g = scipy.optimize.brentq(bw_error, grid[sign[0]], grid[sign[0] + 1], xtol=1e-10)
    return scaled(log_g), 10 ** log_g

TABLE2_READINGS = ("per-sample", "continuous")


def table2_parameters(name: str, ts: float = 5e-4, reading: str = "per-sample") -> dict[str, float]:
    """Controller parameters of Table 2 column ``name`` (before rescaling; tau = 2 ts, which Table 2 omits).

    reading: how the printed Kp, Ki, Kd are read. "per-sample" (default): gains of the DSP's discrete PID
    u_k = Kp e_k + Ki sum(e) + Kd (e_k - e_k-1), i.e. Ki/Ts and Kd*Ts in continuous time (PD zero near 17 Hz,
    integral zero near 1 Hz, below the 56-73 Hz CLBW). "continuous": as printed; the PD zero Kp/Kd is then at
    0.008 Hz, a pure damper with almost no position stiffness on an SI plant.
    """
    if reading not in TABLE2_READINGS:
        raise ValueError(f"reading must be one of {TABLE2_READINGS}, got {reading!r}")
    column = TABLE2[name]
    params = {k: float(column[k]) for k in DESIGN_NAMES} | {"tau": 2 * ts, "Ts": ts}
    if reading == "per-sample":
        params |= {"Ki": params["Ki"] / ts, "Kd": params["Kd"] * ts}
    return params


def table2_comparison(plant: JointModel | control.LTI, ts: float = 5e-4, delay_samples: int = 1,
                      tuned: TuningResult | None = None, reading: str = "per-sample") -> list[dict[str, float | str]]:
    """One row per Table 2 column (paper figures beside ours, after rescaling to the paper's CLBW), plus the
    tuned design when given; ``reading`` as :func:`table2_parameters`."""
    rows: list[dict[str, float | str]] = []
    for name, column in TABLE2.items():
        params = table2_parameters(name, ts, reading)
        scaled, g = rescale_to_bandwidth(params, plant, column["CLBW"], delay_samples)
        m = loop_margins(scaled, plant, delay_samples)
        rows.append({"design": f"Table 2 {name}", "scale": g, **{f"paper {k}": column[k] for k in _PAPER_FIGURES},
                     "GM": m.gm_db, "PM": m.pm_deg, "CLBW": m.bandwidth_hz, "S": m.s_below_bw, "Ms": m.ms,
                     "DM": m.disk_margin, "tau_cl": m.tau_cl, "stable": m.stable})
    if tuned is not None:
        m = loop_margins(tuned.parameters, plant, tuned.delay_samples)
        rows.append({"design": "tuned", "scale": 1.0, **{f"paper {k}": math.nan for k in _PAPER_FIGURES},
                     "GM": m.gm_db, "PM": m.pm_deg, "CLBW": m.bandwidth_hz, "S": m.s_below_bw, "Ms": m.ms,
                     "DM": m.disk_margin, "tau_cl": m.tau_cl, "stable": m.stable})
    return rows


def format_comparison(rows: list[dict[str, float | str]]) -> str:
    """Plain-text table of ``table2_comparison`` rows (paper figure / ours)."""
    head = (f"{'design':<12} {'scale g':>9} {'GM paper/ours [dB]':>19} {'PM paper/ours [deg]':>20} "
            f"{'CLBW paper/ours [Hz]':>21} {'S<CLBW paper/ours':>18} {'Ms':>5} {'disk':>5} {'tau_cl [ms]':>11}")
    lines = [head, "-" * len(head)]

    def paper(key: str, width: int) -> str:
        return f"{'-' if math.isnan(r[key]) else format(r[key], '.3g'):>{width}}"
    for r in rows:
        lines.append(f"{r['design']:<12} {r['scale']:>9.3g} {paper('paper GM', 9)} /{r['GM']:>7.3g} "
                     f"{paper('paper PM', 10)} /{r['PM']:>7.3g} {paper('paper CLBW', 11)} /{r['CLBW']:>7.3g} "
                     f"{paper('paper S', 8)} /{r['S']:>7.3g} {r['Ms']:>5.2f} {r['DM']:>5.2f} "
                     f"{r['tau_cl'] * 1e3:>11.4g}")
    return "\n".join(lines)


def comparison_markdown(rows: list[dict[str, float | str]]) -> str:
    """README table of ``table2_comparison`` rows: paper figure / ours for GM, PM, CLBW and max |S| < CLBW."""
    def pair(r: dict, key: str, fmt: str) -> str:
        paper = r[f"paper {key}"]
        ours = format(r[key], fmt)
        return ours if isinstance(paper, float) and math.isnan(paper) else f"{format(paper, fmt)} / {ours}"
    lines = ["| design | Kp,Ki,Kd scale | GM [dB] paper / ours | PM [deg] paper / ours | CLBW [Hz] paper / ours "
             "| max\\|S\\| below CLBW paper / ours | Ms | disk margin | tau_cl [ms] |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['design']} | {r['scale']:.3g} | {pair(r, 'GM', '.2f')} | {pair(r, 'PM', '.1f')} | "
                     f"{pair(r, 'CLBW', '.1f')} | {pair(r, 'S', '.2f')} | {r['Ms']:.2f} | {r['DM']:.2f} | "
                     f"{r['tau_cl'] * 1e3:.4g} |")
    return "\n".join(lines)
