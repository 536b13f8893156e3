"""Bode plot of the Cheung joint FMU (eqs. 6-8: K/(s(s+alpha)) times a resonance/antiresonance pair),
linearised through the FMU's own directional derivatives, with the paper's transfer function beside it.

Run: .venv/bin/python -m harness.examples.joint_bode --out build/cheung_joint_bode.png
"""
from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import control
import numpy as np

from motiontwin.fmus import build
from motiontwin.harness.linearize import linearize
from motiontwin.harness.recording import write_figure

CLASS = "MotionTwin.Plants.CheungJoint"


def paper_transfer_function(K: float, alpha: float, omega: float, zeta: float, omega_bar: float,
                            zeta_bar: float) -> control.TransferFunction:
    """L(s) H(s) of Cheung eqs. (6)-(8) with one pair: K/(s(s+alpha)) (omega^2/omega_bar^2) (s^2+2 zb wb s+wb^2)/(s^2+2 z w s+w^2)."""
    s = control.tf("s")
    return (K / (s * (s + alpha)) * (omega ** 2 / omega_bar ** 2)
            * (s ** 2 + 2 * zeta_bar * omega_bar * s + omega_bar ** 2) / (s ** 2 + 2 * zeta * omega * s + omega ** 2))


def joint_frequency_response(fmu: Path, frequencies_hz: np.ndarray) -> np.ndarray:
    """Complex response q/u of the FMU's linearisation at ``frequencies_hz``."""
    sys = linearize(fmu, ["u"], ["q"])
    return np.array([complex(sys(2j * np.pi * f)) for f in frequencies_hz])


def main(argv: list[str] | None = None) -> dict[str, float]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", type=Path, default=Path("build") / "cheung_joint_bode.png")
    args = parser.parse_args(argv)
    model = build.load_model(CLASS)
    params = {p.name: float(p.start) for p in model.parameters}
    f = np.logspace(0, np.log10(2000), 2000)
    with tempfile.TemporaryDirectory() as tmp:
        fmu = build.build_fmu(model, tmp, "3.0").path
        fmu_response = joint_frequency_response(fmu, f)
    paper = paper_transfer_function(*(params[k] for k in ("K", "alpha", "omega", "zeta", "omega_bar", "zeta_bar")))
    paper_response = np.array([complex(paper(2j * np.pi * fk)) for fk in f])
    # the resonance shows as a peak and the antiresonance as a dip of |s^2 q/u| (the acceleration response)
    accel = np.abs(fmu_response * (2j * np.pi * f) ** 2)
    peak_hz, dip_hz = f[np.argmax(accel)], f[np.argmin(accel)]
    fig, (ax_mag, ax_phase) = plt.subplots(2, 1, sharex=True, figsize=(7, 5))
    ax_mag.loglog(f, np.abs(fmu_response), label="FMU linearisation (directional derivatives)")
    ax_mag.loglog(f, np.abs(paper_response), "k--", label="paper eqs. (6)-(8)")
    ax_phase.semilogx(f, np.degrees(np.unwrap(np.angle(fmu_response))))
    ax_phase.semilogx(f, np.degrees(np.unwrap(np.angle(paper_response))), "k--")
    for ax in (ax_mag, ax_phase):
        ax.axvline(params["omega"] / (2 * np.pi), color="r", lw=0.8, ls=":")
        ax.axvline(params["omega_bar"] / (2 * np.pi), color="g", lw=0.8, ls=":")
    ax_mag.set_ylabel("|q/u| [m/N]")
    ax_phase.set_ylabel("phase [deg]")
    ax_phase.set_xlabel("frequency [Hz]  (red: omega, green: omega_bar)")
    ax_mag.legend()
    ax_mag.set_title(CLASS)
    fig.tight_layout()
    write_figure(args.out, fig, dpi=120)
    plt.close(fig)
    result = {"resonance_hz": float(peak_hz), "antiresonance_hz": float(dip_hz),
              "omega_hz": params["omega"] / (2 * np.pi), "omega_bar_hz": params["omega_bar"] / (2 * np.pi),
              "max_relative_difference": float(np.max(np.abs(fmu_response - paper_response) / np.abs(paper_response)))}
    for key, value in result.items():
        print(f"{key}: {value:.6g}")
    print(args.out)
    return result


if __name__ == "__main__":
    main()
