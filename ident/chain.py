"""Compiled sample-by-sample recurrence of a CasADi step function (C driver ``chain.c``).

A step function ``fn(s, w, theta, pfix) -> (s_next, y_1, ..., y_m)`` (CasADi SX, the single source of the
model) is turned into C by CasADi's code generator, compiled together with the model-agnostic driver into a
shared library cached under ``$XDG_CACHE_HOME/motiontwin/ident`` by the hash of the generated source, and
called through ctypes on numpy arrays: ``s_k`` is carried inside C, ``w_k`` is column k of W. This replaces
``mapaccum`` over long recordings, whose expression graph grows with the number of samples.
Nothing here knows about units; the caller's are kept.
"""
from __future__ import annotations

import ctypes
import os
import threading
from pathlib import Path

import casadi as ca
import numpy as np

from motiontwin.fmus import clib

__all__ = ["available", "compile_functions", "NativeChain", "native_chains"]

DRIVER = Path(__file__).with_name("chain.c")

#: generated sources below this size (one axis's augmented model and its sensitivity step, 10-250 kB) are
#: compiled at -O1: gcc takes 30 % less time (1.61 -> 1.13 s on a 120 kB Coulomb-friction chain) and a whole
#: single-axis diagnosis on a warm cache runs no slower (49.5 / 49.5 s against 49.0 / 48.3 s of CPU at -O1,
#: the same diagnosis.json); the test suite compiles about 450 such chains on an empty cache
SMALL_SOURCE = 250_000
#: generated sources above this size (an inlined sensitivity step of a large plant: megabytes of straight-line
#: code) are compiled with ``clib.LARGE_SOURCE_FLAGS`` (-O1 and gcc's reload limit): gcc -O2 takes minutes on
#: them, with the same IEEE results (-ffp-contract=off, no fast-math); on the Hexapod smoke bundle
#: (``bench_hexapod.py --smoke``, an empty cache) the limit took 133.7 -> 85.0 s, warm 20.4 / 18.2 s against
#: 20.5 / 19.1 s, the same lines. Those between keep -O2 (a coupled plant's called-function form, about 0.4 MB,
#: compiles at -O2 in 6.5 s of CPU and runs its Jacobian chain 1.2x faster than at -O1)
LARGE_SOURCE = 1_000_000
#: the chains are built for the host's instructions, which they never leave (the cache key holds the CPU,
#: :func:`clib.host_cpu`), still IEEE (-ffp-contract=off, no fast-math: the same results to the last digit). Measured
#: side by side (one worker each): the 4-DOF diagnosis's chains 225.6 -> 187.7 s of CPU, a 1.5 s Hexapod bundle's
#: (-O1 sources) 282.6 -> 224.7 s, the same answers; small single-axis chains unchanged. A compiler that refuses
#: the flag gets the portable build.
HOST_FLAG = "-march=native"
_LOCK = threading.Lock()
_LOADED: dict[str, ctypes.CDLL] = {}
_double_p = ctypes.POINTER(ctypes.c_double)


def available() -> bool:
    """True when a C compiler is found and ``MOTIONTWIN_NATIVE_CHAIN`` is not ``0`` (else callers use
    CasADi's own ``mapaccum`` chain)."""
    return os.environ.get("MOTIONTWIN_NATIVE_CHAIN", "1") != "0" and clib.compiler() is not None


def compile_functions(functions: list[ca.Function]) -> ctypes.CDLL:
    """Generate C for ``functions`` (CasADi C API), compile with the driver, load; cached by source hash."""
    source = _generate(functions)
    sources = {"model.c": source, DRIVER.name: DRIVER.read_text()}
    level = optimisation(len(source))
    with _LOCK:
        path = str(_first_built(sources, [(*level, HOST_FLAG), level, level[:1]]))
        if path not in _LOADED:
            lib = ctypes.CDLL(path)
            lib.mt_chain.restype = ctypes.c_int
            lib.mt_chain.argtypes = [ctypes.c_void_p, ctypes.c_long, ctypes.c_int, _double_p, _double_p,
                                     ctypes.c_int, _double_p, _double_p, ctypes.c_int,
                                     ctypes.POINTER(ctypes.c_int), ctypes.POINTER(_double_p),
                                     ctypes.c_long, ctypes.c_long, ctypes.c_long, ctypes.c_long]
            _LOADED[path] = lib
        return _LOADED[path]


def optimisation(size: int) -> tuple[str, ...]:
    """The optimisation flags of a generated source of ``size`` characters (``SMALL_SOURCE``, ``LARGE_SOURCE``)."""
    if size < SMALL_SOURCE:
        return ("-O1",)
    return ("-O2",) if size <= LARGE_SOURCE else clib.LARGE_SOURCE_FLAGS


def _generate(functions: list[ca.Function]) -> str:
    gen = ca.CodeGenerator("model.c", {"with_header": False, "casadi_int": "long long int",
                                       "casadi_real": "double"})
    for fn in functions:
        gen.add(fn)
    return gen.dump()


def _first_built(sources: dict[str, str], attempts: list[tuple[str, ...]]) -> Path:
    """The library built with the first of ``attempts`` (flag sets, each before ``clib.CFLAGS[1:]``) that the
    compiler accepts; the last one's error when none does."""
    *first, last = dict.fromkeys(attempts)
    for flags in first:
        try:
            return clib.cached_library(sources, "ident", "chain", flags + clib.CFLAGS[1:])
        except clib.CompileError:
            continue
    return clib.cached_library(sources, "ident", "chain", last + clib.CFLAGS[1:])


def _dense(fn: ca.Function) -> None:
    for i in range(fn.n_in()):
        if not fn.sparsity_in(i).is_dense():
            raise ValueError(f"{fn.name()}: input {i} is sparse; the compiled chain needs dense inputs")
    for i in range(fn.n_out()):
        if not fn.sparsity_out(i).is_dense():
            raise ValueError(f"{fn.name()}: output {i} is sparse; densify it before compiling the chain")


class NativeChain:
    """``fn`` applied ``n_samples`` times in C: ``chain(s0, W, theta, pfix)`` returns, per output
    y_j of ``fn``, an array of shape (n_samples, size of y_j)."""

    def __init__(self, lib: ctypes.CDLL, fn: ca.Function, n_samples: int):
        _dense(fn)
        if fn.n_in() != 4:
            raise ValueError(f"{fn.name()}: expected inputs (s, w, theta, pfix), got {fn.n_in()}")
        self._lib, self._fn, self.n_samples = lib, fn, int(n_samples)
        self._address = ctypes.cast(getattr(lib, fn.name()), ctypes.c_void_p).value
        self._ns = fn.numel_in(0)
        self._nw = fn.numel_in(1)
        if fn.numel_out(0) != self._ns:
            raise ValueError(f"{fn.name()}: next state has {fn.numel_out(0)} entries, state {self._ns}")
        self._sizes = [fn.numel_out(j) for j in range(1, fn.n_out())]
        self._work = (fn.sz_arg(), fn.sz_res(), fn.sz_iw(), fn.sz_w())

    def __call__(self, s0, W, theta, pfix) -> list[np.ndarray]:
        n = self.n_samples
        s0 = np.ascontiguousarray(np.asarray(s0, dtype=float).ravel())
        W = np.asarray(W, dtype=float)
        if W.shape != (self._nw, n):
            raise ValueError(f"W has shape {W.shape}, the chain needs {(self._nw, n)}")
        cols = np.asfortranarray(W)   # column k contiguous
        theta = np.ascontiguousarray(np.asarray(theta, dtype=float).ravel())
        pfix = np.ascontiguousarray(np.asarray(pfix, dtype=float).ravel())
        for name, arr, size in (("s0", s0, self._ns), ("theta", theta, self._fn.numel_in(2)),
                                ("pfix", pfix, self._fn.numel_in(3))):
            if arr.size != size:
                raise ValueError(f"{name} has {arr.size} entries, the chain needs {size}")
        outs = [np.empty((n, size)) for size in self._sizes]
        ptrs = (_double_p * max(len(outs), 1))(*[o.ctypes.data_as(_double_p) for o in outs])
        sizes = (ctypes.c_int * max(len(outs), 1))(*self._sizes)
        status = self._lib.mt_chain(self._address, n, self._ns, _ptr(s0), cols.ctypes.data_as(_double_p),
                                    self._nw, _ptr(theta), _ptr(pfix), len(outs), sizes, ptrs, *self._work)
        if status < 0:
            raise MemoryError("compiled chain: out of memory")
        if status > 0:
            raise RuntimeError(f"{self._fn.name()} failed at sample {status - 1}")
        return outs


def _ptr(array: np.ndarray):
    return array.ctypes.data_as(_double_p) if array.size else None


def native_chains(functions: list[ca.Function], n_samples: int) -> list[NativeChain]:
    """One compiled library for all ``functions``; a chain of ``n_samples`` samples for each."""
    lib = compile_functions(functions)
    return [NativeChain(lib, fn, n_samples) for fn in functions]
