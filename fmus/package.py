"""Compile the generated and runtime C sources and pack them into an ``.fmu`` archive, atomically."""
from __future__ import annotations

import hashlib
import os
import re
import shutil
import subprocess
import zipfile
from pathlib import Path


from motiontwin.fmus import clib
from motiontwin.fmus.files import atomic_path

RUNTIME_DIR = Path(__file__).parent / "runtime"
FMI_HEADERS = {
    "2.0": ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h"),
    "3.0": ("fmi3Functions.h", "fmi3FunctionTypes.h", "fmi3PlatformTypes.h"),
}
PLATFORM_DIR = {"2.0": "linux64", "3.0": "x86_64-linux"}
CFLAGS = ("-O2", "-fPIC", "-std=c99", "-fvisibility=hidden", "-Wall", "-Wno-unused-parameter",
          "-Wno-unused-variable", "-Wno-unused-function")
# Generated files of this size or more compile with ``clib.LARGE_SOURCE_FLAGS`` (-O1 and gcc's reload limit): gcc
# -O2's register allocation on the Hexapod's 1.7 MB of straight-line CasADi code takes 111 s against 56 s at -O1
# (the whole library fixture waits for it), and the reload limit takes -O1's 43.9 s to 31.5 s.
LARGE_SOURCE_BYTES = 1_000_000


class BuildError(Exception):
    """The C sources of an FMU did not compile; the message carries the compiler's output."""


def runtime_sources(fmi_version: str) -> list[Path]:
    """The model-agnostic runtime files an FMU of ``fmi_version`` needs (C files and headers)."""
    import fmpy  # here, not at import: loading a model for identification needs no fmpy

    other = "fmi3.c" if fmi_version == "2.0" else "fmi2.c"
    files = sorted(p for p in RUNTIME_DIR.iterdir() if p.suffix in (".c", ".h") and p.name != other)
    headers = Path(fmpy.__file__).parent / "c-code"
    return files + [headers / h for h in FMI_HEADERS[fmi_version]]


def compile_binary(src_dir: Path, c_files: list[str], output: Path) -> None:
    """gcc the C files of ``src_dir`` into the shared library ``output`` (only libc and libm needed).

    Object files are cached by the hash of compiler, flags, the C file and the headers of ``src_dir`` it
    includes (directly or through other headers): the runtime compiles once for all models, and a model's
    generated code (which includes no FMI header) once for FMI 2.0 and 3.0.
    """
    cc = os.environ.get("CC", "gcc")
    cache = clib.cache_dir("objects")
    cache.mkdir(parents=True, exist_ok=True)
    objects = [str(_object(cc, src_dir, name, cache)) for name in c_files]
    _run([cc, "-shared", "-static-libgcc", *objects, "-o", str(output), "-lm"], f"linking {output.name}")


def _object(cc: str, src_dir: Path, name: str, cache: Path) -> Path:
    """The cached object file of the C file ``name``: at ``CFLAGS``, or for a generated file of
    ``LARGE_SOURCE_BYTES`` or more with ``clib.LARGE_SOURCE_FLAGS``, at plain -O1 when the compiler refuses
    gcc's reload limit."""
    if (src_dir / name).stat().st_size < LARGE_SOURCE_BYTES:
        return _compiled(cc, src_dir, name, cache, CFLAGS)
    try:
        return _compiled(cc, src_dir, name, cache, (*clib.LARGE_SOURCE_FLAGS, *CFLAGS[1:]))
    except BuildError:
        return _compiled(cc, src_dir, name, cache, (*clib.LARGE_SOURCE_FLAGS[:1], *CFLAGS[1:]))


def _compiled(cc: str, src_dir: Path, name: str, cache: Path, flags: tuple[str, ...]) -> Path:
    """``name`` compiled with ``flags``, cached by compiler, flags, the file and the local headers it includes."""
    key = hashlib.sha256((cc + " ".join(flags)).encode())
    for h in _local_headers(src_dir, name):
        key.update(h.encode() + b"\0" + (src_dir / h).read_bytes())
    key.update((src_dir / name).read_bytes())
    obj = cache / f"{key.hexdigest()}.o"
    if not obj.exists():
        with atomic_path(obj) as tmp:
            _run([cc, *flags, f"-I{src_dir}", "-c", str(src_dir / name), "-o", str(tmp)], f"compiling {name}")
    return obj


_INCLUDE = re.compile(r'^\s*#\s*include\s*"([^"]+)"', re.MULTILINE)


def _local_headers(src_dir: Path, name: str) -> list[str]:
    """Headers of ``src_dir`` that ``name`` includes with ``#include "..."``, transitively, sorted."""
    found: set[str] = set()
    pending = [name]
    while pending:
        text = (src_dir / pending.pop()).read_text(errors="replace")
        for header in _INCLUDE.findall(text):
            if header not in found and (src_dir / header).is_file():
                found.add(header)
                pending.append(header)
    return sorted(found)


def _run(cmd: list[str], what: str) -> None:
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise BuildError(f"{what} failed:\n{proc.stderr.strip()}")


def pack(staging: Path, fmu_path: Path) -> Path:
    """Zip the folder ``staging`` into ``fmu_path`` through a temporary file in the same folder; the FMU
    gets the ordinary permissions of a new file (:func:`motiontwin.fmus.files.ordinary_file_mode`)."""
    fmu_path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(fmu_path) as tmp, zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zf:
        for path in sorted(staging.rglob("*")):
            if path.is_file():
                zf.write(path, path.relative_to(staging).as_posix())
    return fmu_path


def copy_sources(files: list[Path], dest: Path) -> list[str]:
    dest.mkdir(parents=True, exist_ok=True)
    for f in files:
        shutil.copy2(f, dest / f.name)
    return [f.name for f in files]
