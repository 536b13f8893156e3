"""Benchmark (not a test): wall time per doStep of the 4-DOF closed loop in pure C (tests/c/closed_loop_timing.c),
without fmpy or Python in the loop: four RobustJointController instances (Table 2 designs as in
harness.comparison) around CheungManipulator, FMI 2.0, Ts = 5e-4 s, the reference of bench_manipulator.py
(the paper's substrate move, back and forth every 0.25 s). Prints the plant's and the controllers' cost per
tick (plant split into ticks while the reference moves and at rest) and the plant's solver statistics.

Run: .venv/bin/python tests/benchmarks/bench_closed_loop_c.py [SIMULATED_SECONDS] [--callgrind] [--smoke]
(--callgrind runs 1 s under valgrind's callgrind and prints the instruction profile: load-independent;
--smoke: 0.05 s simulated.) The driver prints the ratio line (real-time factor: the baseline is real time).
"""
from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import fmpy
import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).parent))

import bench_manipulator  # noqa: E402
from motiontwin import comparison  # noqa: E402
from ratios import smoke  # noqa: E402

DRIVER = ROOT / "tests" / "c" / "closed_loop_timing.c"


def write_inputs(path: Path, fmus: dict[str, Path], n: int) -> None:
    """The driver's input file: controller parameters by value reference, holding forces, reference rows."""
    ref = bench_manipulator.reference(n)
    with comparison.PlantDynamics(fmus["plant"]) as dyn:
        masses = np.diag(dyn.mass_matrix(ref[0, 0])).copy()
        holding = dyn.inverse(ref[0, 0], np.zeros(4), np.zeros(4))
    designs = comparison.table2_designs(masses, 5.0)
    vr = {v.name: v.valueReference for v in fmpy.read_model_description(str(fmus["robust"])).modelVariables}
    names = [k for k in designs[0] if k in vr and k != "Ts"]
    lines = [str(len(names))]
    lines += [" ".join(f"{vr[k]} {float(d[k])!r}" for k in names) for d in designs]
    lines += [" ".join(repr(float(h)) for h in holding), str(n)]
    lines += [" ".join(repr(float(v)) for v in row.T.ravel()) for row in ref]
    path.write_text("\n".join(lines) + "\n")


def binary(fmu: Path, into: Path) -> tuple[str, str]:
    """Unzip ``fmu`` into ``into``; return its shared library and guid."""
    with zipfile.ZipFile(fmu) as zf:
        zf.extractall(into)
    md = fmpy.read_model_description(str(fmu))
    return str(into / "binaries" / "linux64" / f"{md.coSimulation.modelIdentifier}.so"), md.guid


def main() -> None:
    small = smoke()
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    callgrind = "--callgrind" in sys.argv
    simulated = float(args[0]) if args else (1.0 if callgrind else (0.05 if small else 4.0))
    n = round(simulated / comparison.TS)
    with tempfile.TemporaryDirectory() as tmp:
        tmp_path = Path(tmp)
        fmus = comparison.build_fmus(tmp_path / "fmus")
        inputs = tmp_path / "inputs.txt"
        write_inputs(inputs, fmus, n)
        driver = tmp_path / "closed_loop_timing"
        headers = Path(fmpy.__file__).parent / "c-code"
        subprocess.run(["gcc", "-O2", "-std=gnu99", f"-I{headers}", str(DRIVER), "-ldl", "-o", str(driver)],
                       check=True)
        plant = binary(fmus["plant"], tmp_path / "plant")
        ctrl = binary(fmus["robust"], tmp_path / "ctrl")
        cmd = [str(driver), *plant, *ctrl, str(inputs)]
        if callgrind and shutil.which("valgrind"):
            out = tmp_path / "callgrind.out"
            subprocess.run(["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}", *cmd], check=True)
            report = subprocess.run(["callgrind_annotate", str(out)], capture_output=True, text=True).stdout
            print("\n".join(report.splitlines()[:45]))
        else:
            subprocess.run(cmd, check=True)


if __name__ == "__main__":
    main()
