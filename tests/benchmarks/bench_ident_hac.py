"""Coverage of the 95 % intervals with coloured (AR(1)) noise: white-noise formula vs HAC (Newey-West) standard
deviations, for linear least squares and the output-error refit (the Monte Carlo of tests/test_ident_hac.py, printed).

    .venv/bin/python tests/benchmarks/bench_ident_hac.py [--smoke]   (--smoke: 10 and 2 seeds)

Ratios: the lowest HAC coverage over the nominal 95 % (the baseline), for both Monte Carlos.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))

from ratios import ratio, smoke  # noqa: E402
from tests.test_ident_hac import least_squares_coverage, output_error_coverage  # noqa: E402


def main() -> int:
    ls_seeds, oe_seeds = (10, 2) if smoke() else (200, 100)
    t0 = time.perf_counter()
    ls = least_squares_coverage(ls_seeds)
    oe = output_error_coverage(oe_seeds)
    pct = lambda a: " / ".join(f"{100 * v:.1f}" for v in a)   # noqa: E731
    print("95 % interval coverage [%] per parameter")
    print(f"least squares, {ls_seeds} seeds, AR(1) phi 0.8: HAC {pct(ls['ar1_hac'])}; white formula {pct(ls['ar1_white'])}")
    print(f"least squares, {ls_seeds} seeds, white noise:  HAC {pct(ls['white_hac'])}; white formula {pct(ls['white_white'])}"
          f"; mean HAC/white std {pct(ls['white_ratio'] / 100)}")
    print(f"output error (m, d), {oe_seeds} seeds, AR(1) phi 0.9: HAC {pct(oe['ar1_hac'])}; white formula "
          f"{pct(oe['ar1_white'])}; bandwidth {np.min(oe['lags'])}-{np.max(oe['lags'])} samples")
    print(f"{time.perf_counter() - t0:.1f} s")
    ratio("hac.least_squares_ar1_coverage", float(np.min(ls["ar1_hac"])) / 0.95, "nominal 95 % coverage (lowest "
          "parameter, HAC)")
    ratio("hac.output_error_ar1_coverage", float(np.min(oe["ar1_hac"])) / 0.95, "nominal 95 % coverage (lowest "
          "parameter, HAC)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
