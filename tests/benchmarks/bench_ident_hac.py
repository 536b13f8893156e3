"""Coverage of the 95 % intervals with coloured (AR(1)) noise: white-noise formula vs HAC (Newey-West) standard
deviations, for linear least squares and the output-error refit (the Monte Carlo of tests/test_ident_hac.py, printed).

    .venv/bin/python tests/benchmarks/bench_ident_hac.py
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from tests.test_ident_hac import least_squares_coverage, output_error_coverage  # noqa: E402


def main() -> int:
    t0 = time.perf_counter()
    ls = least_squares_coverage()
    oe = output_error_coverage()
    pct = lambda a: " / ".join(f"{100 * v:.1f}" for v in a)   # noqa: E731
    print("95 % interval coverage [%] per parameter")
    print(f"least squares, 200 seeds, AR(1) phi 0.8: HAC {pct(ls['ar1_hac'])}; white formula {pct(ls['ar1_white'])}")
    print(f"least squares, 200 seeds, white noise:  HAC {pct(ls['white_hac'])}; white formula {pct(ls['white_white'])}"
          f"; mean HAC/white std {pct(ls['white_ratio'] / 100)}")
    print(f"output error (m, d), 100 seeds, AR(1) phi 0.9: HAC {pct(oe['ar1_hac'])}; white formula "
          f"{pct(oe['ar1_white'])}; bandwidth {np.min(oe['lags'])}-{np.max(oe['lags'])} samples")
    print(f"{time.perf_counter() - t0:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
