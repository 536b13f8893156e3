"""Host shared libraries compiled from C sources on first use and cached by content hash.

Used by the compiled loops that run beside the FMUs on the user's machine (the harness's inner loop,
the identification's sample chain): one compiler call per distinct source, compiler and flags, the
library written atomically into ``$XDG_CACHE_HOME/motiontwin/<folder>``. FMU binaries are built by
:mod:`fmus.package` instead (object cache, static libgcc, shipped inside the archive).
"""
from __future__ import annotations

import hashlib
import os
import platform
import shutil
import subprocess
import tempfile
from pathlib import Path

from motiontwin.fmus.files import move_file

CFLAGS = ("-O2", "-shared", "-fPIC", "-std=c99", "-ffp-contract=off")
#: flags for a generated source of a megabyte or more (an inlined plant derivative and its sensitivities: straight-
#: line code of tens of thousands of statements): -O1, where -O2 takes minutes, and gcc's register allocator
#: considering at most 50 pseudo-registers per reload (default 500). Register allocation does not change the
#: arithmetic. Measured: the Hexapod's plant derivative in its sensitivity step 39 -> 19 s of gcc (its
#: hard-register assignment took 27 of the 39 s); the Hexapod FMU's 1.77 MB model file 43.9 -> 31.5 s. A compiler
#: that refuses the limit gets plain -O1 (``LARGE_SOURCE_FLAGS[:1]``).
LARGE_SOURCE_FLAGS = ("-O1", "--param=lra-max-considered-reload-pseudos=50")


class CompileError(RuntimeError):
    """The C compiler failed; the message carries its output."""


def compiler() -> str | None:
    """The C compiler (``$CC``, default gcc) when it is on the PATH, else None."""
    cc = os.environ.get("CC", "gcc")
    return cc if shutil.which(cc) else None


def host_cpu() -> str:
    """The host CPU's model and instruction-set features (from ``/proc/cpuinfo``, else :mod:`platform`): part of
    the cache key of a library built with ``-march=native``, so that a cache folder shared by machines with
    different CPUs never hands one a library built for another's instructions."""
    keys = ("model name", "flags", "Features", "CPU implementer", "CPU part")
    found: dict[str, str] = {}
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as info:
            for line in info:
                key, _, value = line.partition(":")
                if key.strip() in keys:
                    found.setdefault(key.strip(), value.strip())
    except OSError:
        pass
    return "\n".join(f"{k}={v}" for k, v in sorted(found.items())) or f"{platform.machine()} {platform.processor()}"


def cache_dir(folder: str) -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "motiontwin" / folder


def cached_library(sources: dict[str, str], folder: str, prefix: str, flags: tuple[str, ...] = CFLAGS) -> Path:
    """Path of the shared library built from ``sources`` (file name -> C text), compiled once per
    (sources, compiler, flags) into ``cache_dir(folder)/prefix-HASH.so`` (``flags``: the compiler flags; with
    ``-march=native`` the host CPU, :func:`host_cpu`, is part of the key).

    Raises CompileError when there is no compiler or it fails (nothing is left in the cache then).
    """
    cc = compiler()
    if cc is None:
        raise CompileError(f"no C compiler '{os.environ.get('CC', 'gcc')}' found (set CC)")
    digest = hashlib.sha256("\0".join([cc, " ".join(flags)]).encode())
    if "-march=native" in flags:
        digest.update(b"\0" + host_cpu().encode())
    for name in sorted(sources):
        digest.update(b"\0" + name.encode() + b"\0" + sources[name].encode())
    cache = cache_dir(folder)
    library = cache / f"{prefix}-{digest.hexdigest()[:24]}.so"
    if library.exists():
        return library
    cache.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=cache) as tmp:
        files = []
        for name, text in sources.items():
            (Path(tmp) / name).write_text(text)
            files.append(str(Path(tmp) / name))
        out = Path(tmp) / "lib.so"
        proc = subprocess.run([cc, *flags, *files, "-o", str(out), "-lm"], capture_output=True, text=True)
        if proc.returncode != 0:
            raise CompileError(f"compiling {', '.join(sorted(sources))} failed:\n{proc.stderr[-2000:]}")
        move_file(out, library)
    return library
