"""The identification's compiled chain is built for the host CPU (``-march=native``): the same IEEE results as the
portable build, a cache entry per CPU, and the portable build when the compiler refuses the flag."""
from __future__ import annotations

from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from motiontwin.fmus import clib
from motiontwin.ident import chain
from tests.compiler_util import wrapped_compiler

N = 400


def _step() -> ca.Function:
    """A stiff nonlinear oscillator with Coulomb friction, RK4 over 4 substeps: transcendental calls and long
    straight-line code, where a compiler allowed to reassociate or contract would change the last digits."""
    s, w, theta, pfix = ca.SX.sym("s", 2), ca.SX.sym("w", 1), ca.SX.sym("theta", 3), ca.SX.sym("pfix", 1)

    def f(x):
        return ca.vertcat(x[1], (w[0] - theta[0] * x[0] - theta[1] * x[1]
                                 - theta[2] * ca.tanh(x[1] / 1e-3) - pfix[0] * ca.sin(x[0])) / 0.7)
    h, x = 5e-4 / 4, s
    for _ in range(4):
        k1 = f(x)
        k2 = f(x + h / 2 * k1)
        k3 = f(x + h / 2 * k2)
        k4 = f(x + h * k3)
        x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return ca.Function("flagstep", [s, w, theta, pfix], [x, ca.vertcat(x[0], ca.exp(-x[1] ** 2))])


def _run(fn: ca.Function) -> np.ndarray:
    (one,) = chain.native_chains([fn], N)
    drive = np.sin(np.arange(N) * 0.05)[None, :] * 3.0
    return one([1e-3, 0.0], drive, [400.0, 2.0, 0.3], [0.5])[0]


@pytest.fixture
def cache(monkeypatch, tmp_path) -> Path:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    return tmp_path / "motiontwin" / "ident"


def test_host_build_gives_the_portable_builds_results_bit_for_bit(cache, monkeypatch):
    if clib.compiler() is None:
        pytest.skip("no C compiler")
    fn = _step()
    native = _run(fn)
    monkeypatch.setattr(chain, "HOST_FLAG", "-O2")     # the portable -O2 build of the same source
    portable = _run(fn)
    assert len(list(cache.glob("chain-*.so"))) == 2
    assert np.all(np.isfinite(native)) and np.ptp(native) > 0
    np.testing.assert_array_equal(native, portable)
    # CasADi's own evaluation of the same recurrence agrees to round-off (the chain computes what it says)
    x, rows = np.array([1e-3, 0.0]), []
    drive = np.sin(np.arange(N) * 0.05) * 3.0
    for k in range(N):
        x_next, y = fn(x, drive[k], [400.0, 2.0, 0.3], [0.5])
        rows.append(np.array(y).ravel())
        x = np.array(x_next).ravel()
    np.testing.assert_allclose(native, np.array(rows), rtol=1e-12, atol=1e-15)


def test_the_cache_key_holds_the_host_cpu(cache, monkeypatch):
    if clib.compiler() is None:
        pytest.skip("no C compiler")
    fn = _step()
    _run(fn)
    _run(fn)
    assert len(list(cache.glob("chain-*.so"))) == 1        # the same CPU: the cached library
    monkeypatch.setattr(clib, "host_cpu", lambda: "model name=another CPU\nflags=sse2")
    chain._LOADED.clear()
    _run(fn)
    assert len(list(cache.glob("chain-*.so"))) == 2        # another CPU: its own build


def test_a_compiler_that_refuses_the_host_flag_gets_the_portable_build(cache, monkeypatch, tmp_path):
    wrapped_compiler(tmp_path, monkeypatch, "cc-without-native", refuse=("-march=native",))
    out = _run(_step())
    assert np.all(np.isfinite(out))
    assert len(list(cache.glob("chain-*.so"))) == 1


def test_a_large_source_gets_the_reload_limit_and_a_compiler_that_refuses_it_plain_o1(cache, monkeypatch, tmp_path):
    """Above ``LARGE_SOURCE`` the chain is compiled with ``clib.LARGE_SOURCE_FLAGS`` (-O1 and gcc's reload limit): the
    same results bit for bit as plain -O1; a compiler refusing the limit (and the host flag) gets plain -O1."""
    log = wrapped_compiler(tmp_path, monkeypatch)
    monkeypatch.setattr(chain, "SMALL_SOURCE", 0)
    monkeypatch.setattr(chain, "LARGE_SOURCE", 0)
    limited = _run(_step())
    assert "--param=lra-max-considered-reload-pseudos=50" in log.read_text().split("\n")[0]
    limit = clib.LARGE_SOURCE_FLAGS
    monkeypatch.setattr(clib, "LARGE_SOURCE_FLAGS", ("-O1",))
    monkeypatch.setattr(chain, "HOST_FLAG", "-O1")
    np.testing.assert_array_equal(limited, _run(_step()))
    wrapped_compiler(tmp_path, monkeypatch, "cc-plain", refuse=("--param=*", "-march=native"))
    monkeypatch.setattr(clib, "LARGE_SOURCE_FLAGS", limit)
    monkeypatch.setattr(chain, "HOST_FLAG", "-march=native")
    chain._LOADED.clear()
    np.testing.assert_array_equal(limited, _run(_step()))


def test_a_small_source_is_built_at_o1_with_the_o2_builds_results_bit_for_bit(cache, monkeypatch, tmp_path):
    """Below ``SMALL_SOURCE`` (one axis's chain) the chain is compiled at -O1, which compiles faster and runs as
    fast; its results are those of the -O2 build to the last bit (IEEE arithmetic, no contraction)."""
    log = wrapped_compiler(tmp_path, monkeypatch)
    small = _run(_step())
    assert log.read_text().split()[0] == "-O1"
    monkeypatch.setattr(chain, "SMALL_SOURCE", 0)
    chain._LOADED.clear()
    o2 = _run(_step())
    assert log.read_text().split("\n")[1].split()[0] == "-O2"
    assert len(list(cache.glob("chain-*.so"))) == 2
    np.testing.assert_array_equal(small, o2)
