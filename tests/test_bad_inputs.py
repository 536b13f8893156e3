"""Every bad input of the fault campaign (issue 26) gives one line naming the file, field or line, with the
documented exit code (1; ``diagnose``: 2 for a bad bundle), through ``motiontwin.cli.main`` in-process; and a
fuzz test over the JSON, TOML and CSV readers: whatever the bytes, a one-line error and never a traceback.

Each case writes its inputs into a fresh folder; the messages were a RecursionError, an IndexError, a bare
``Exception``, a codec or float-conversion message naming no file, or exit 0 with a nonsense fit before.
"""
from __future__ import annotations

import contextlib
import copy
import json
import math
import os
import re
import zipfile
from pathlib import Path
from typing import Callable

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from motiontwin.cli import main
from tests.test_cli_errors import EXPERIMENT, _unprivileged, world_readable_dir  # noqa: F401 (a fixture)
from tests.test_master import PI_LOOP

CONTROLLER = {"kind": "discrete_state_space", "Ts": 0.0005, "inputs": ["r", "q"], "outputs": ["u"],
              "A": [[0.0]], "B": [[0.0, 0.0]], "C": [[0.0]], "D": [[1.0, -1.0]]}
NESTED = "[" * 100_000


@pytest.fixture(scope="module")
def plant_fmu(tmp_path_factory) -> Path:
    """The project's LinearMotorJoint as an FMI 2.0 FMU (built once; the compiled objects are cached)."""
    from motiontwin.fmus import build

    out = tmp_path_factory.mktemp("fmus")
    return build.build(["MotionTwin.Plants.LinearMotorJoint"], out_dir=out, fmi_versions=("2.0",), workers=1)[0].path


def _recording(path: Path, rows: int = 60, jump_at: int | None = None) -> Path:
    """A uniformly sampled recording (time, r, u, q) at 0.5 ms; ``jump_at``: one step of 1.2 ms there."""
    t = [k * 0.0005 + (0.0007 if jump_at is not None and k >= jump_at else 0.0) for k in range(rows)]
    path.write_text("time,r,u,q\n" + "".join(f"{x!r},0,{k % 7 - 3},{0.001 * (k % 5)}\n" for k, x in enumerate(t)))
    return path


def _bundle(root: Path, train: str = "train.csv", **experiment) -> Path:
    """A bundle folder with a library plant, a static controller and two small recordings."""
    folder = root / "bundle"
    folder.mkdir()
    _recording(folder / "train.csv")
    _recording(folder / "validation.csv")
    doc = {"plant": {"class": "MotionTwin.Plants.LinearMotorJoint"}, "controller": CONTROLLER,
           "recordings": {"train": train, "validation": "validation.csv"}, **experiment}
    (folder / "experiment.json").write_text(json.dumps(doc))
    return folder


def _system(root: Path, fmu: Path, **replace: str) -> Path:
    """The PI loop of test_master with ``fmu`` as both FMUs and some lines replaced."""
    text = PI_LOOP.format(pi=fmu, plant=fmu)
    for old, new in replace.items():
        assert old in text
        text = text.replace(old, new)
    (root / "loop.toml").write_text(text)
    return root / "loop.toml"


def _wrong_guid(root: Path, fmu: Path) -> Path:
    """A copy of ``fmu`` whose modelDescription.xml names another GUID: its instantiate returns NULL."""
    broken = root / "third_party.fmu"
    with zipfile.ZipFile(fmu) as src, zipfile.ZipFile(broken, "w") as dst:
        for item in src.infolist():
            data = src.read(item)
            if item.filename == "modelDescription.xml":
                data = re.sub(rb'guid="[^"]*"', b'guid="{00000000-0000-0000-0000-000000000000}"', data)
            dst.writestr(item, data)
    return broken


def _write(root: Path, name: str, content: str | bytes) -> Path:
    path = root / name
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    return path


def _sweep(root: Path, fmu: Path, cases: str) -> Path:
    _system(root, fmu)
    return _write(root, "sweep.toml", 'system = "loop.toml"\n' + cases)


def _binary_bundle(root: Path) -> Path:
    folder = root / "binary"
    folder.mkdir()
    (folder / "experiment.json").write_bytes(b"\xff\xfe\x00{}")
    return folder


def _linked_bundle(root: Path) -> Path:
    folder = _bundle(root, train="link.csv")
    (folder / "link.csv").symlink_to(_recording(root / "elsewhere.csv"))
    return folder


def _huge_bundle(root: Path) -> Path:
    folder = _bundle(root)
    (folder / "experiment.json").write_text("[" + "0," * 8_500_000 + "0]")
    return folder


def _huge_plant_bundle(root: Path) -> Path:
    folder = _bundle(root, plant={"modelica": "plant.mo", "class": "P"})
    (folder / "plant.mo").write_text("model P\n" + "  // padding\n" * 1_307_000 + "end P;\n")
    return folder


def _long_bundle(root: Path) -> Path:
    folder = _bundle(root)
    (folder / "train.csv").write_text("time,r,u,q\n" + "0,0,0,0\n" * 1_000_000)
    return folder


def _nested_bundle(root: Path) -> Path:
    folder = root / "nested"
    folder.mkdir()
    (folder / "experiment.json").write_text(NESTED)
    return folder


# name -> (argv builder from (folder, plant FMU), expected exit code, expected fragment of the message)
CASES: dict[str, tuple[Callable[[Path, Path], list[str]], int, str]] = {
    "diagnose: deeply nested experiment.json": (
        lambda d, f: ["diagnose", str(_nested_bundle(d)), "--out", str(d / "o")],
        2, "experiment.json: invalid JSON (nested too deeply to read)"),
    "writeback --values: deeply nested JSON": (
        lambda d, f: ["writeback", str(f), "--values", str(_write(d, "v.json", NESTED)), "--out", str(d / "n.fmu")],
        1, "v.json: invalid JSON (nested too deeply to read)"),
    "identify oe --values: deeply nested JSON": (
        lambda d, f: ["identify", "oe", str(_recording(d / "r.csv")), "--class", "MotionTwin.Plants.LinearMotorJoint",
                      "--free", "m", "--values", str(_write(d, "v.json", NESTED)), "--out", str(d / "o.json")],
        1, "v.json: invalid JSON (nested too deeply to read)"),
    "validate --lags -3": (
        lambda d, f: ["validate", "-", str(_recording(d / "r.csv")), "--class", "MotionTwin.Plants.LinearMotorJoint",
                      "--lags", "-3"],
        1, "lags = -3: must be a whole number from 1 to 29"),
    "validate --set m=-1 below the Modelica min": (
        lambda d, f: ["validate", "-", str(_recording(d / "r.csv")), "--class", "MotionTwin.Plants.LinearMotorJoint",
                      "--set", "m=-1"],
        1, "parameter m = -1 is below its minimum 1e-09"),
    "validate: a sample-time message prints plain numbers": (
        lambda d, f: ["validate", "-", str(_recording(d / "r.csv", jump_at=40)), "--class",
                      "MotionTwin.Plants.LinearMotorJoint"],
        1, "row 42, column 'time': step 0.0012 s differs from the sample period 0.0005 s"),
    "run: a third-party FMU that fails to instantiate": (
        lambda d, f: ["run", str(_system(d, _wrong_guid(d, f))), "--out", str(d / "o.csv")],
        1, "third_party.fmu): Failed to instantiate model; it logged: [ERROR] logStatusError: Instantiate: token"),
    "run: text for a numeric system-file parameter": (
        lambda d, f: ["run", str(_system(d, f, **{"Kp = 2000.0": "m = \"big\""})), "--out", str(d / "o.csv")],
        1, "loop.toml: [fmus.pi.parameters] m = 'big': expected a number"),
    "run: nan in the system file": (
        lambda d, f: ["run", str(_system(d, f, **{"Kp = 2000.0": "Kp = nan"})), "--out", str(d / "o.csv")],
        1, "[fmus.pi.parameters] Kp: must be a finite number, got nan"),
    "excite: a folder given as the experiment file": (
        lambda d, f: ["excite", str(d), "--out", str(d / "o.csv")],
        1, "is a folder, expected a file"),
    "import: an HDF5 file that is not one": (
        lambda d, f: ["import", str(_write(d, "lab.h5", b"not hdf5 at all")), "--out", str(d / "o.csv")],
        1, "lab.h5: not a readable HDF5 file"),
    "diagnose: binary experiment.json": (
        lambda d, f: ["diagnose", str(_binary_bundle(d)), "--out", str(d / "o")],
        2, "experiment.json: not UTF-8 text (byte 0: invalid start byte)"),
    "diagnose: a recording outside the bundle": (
        lambda d, f: ["diagnose", str(_bundle(d, train="/etc/passwd")), "--out", str(d / "o")],
        2, "field 'recordings.train' names '/etc/passwd', a file outside the bundle folder"),
    "diagnose: a relative path out of the bundle": (
        lambda d, f: ["diagnose", str(_bundle(d, train="../train.csv")), "--out", str(d / "o")],
        2, "pass --allow-outside-paths to read it"),
    "diagnose: a symbolic link out of the bundle": (
        lambda d, f: ["diagnose", str(_linked_bundle(d)), "--out", str(d / "o")],
        2, "field 'recordings.train' names 'link.csv', a file outside the bundle folder"),
    "diagnose --allow-outside-paths: a file that is not a recording is not echoed": (
        lambda d, f: ["diagnose", str(_bundle(d, train="/etc/passwd")), "--out", str(d / "o"),
                      "--allow-outside-paths"],
        2, "/etc/passwd, row 1: required column 'time' missing; not a recording"),
    "diagnose: a recording of 1e6 rows": (
        lambda d, f: ["diagnose", str(_long_bundle(d)), "--out", str(d / "o")],
        2, "train.csv: 1000000 rows, too many (the limit for the samples of one recording read is 500000 rows; "
           "raise it with MOTIONTWIN_MAX_ROWS=1000000"),
    "diagnose: a 17 MB experiment.json": (
        lambda d, f: ["diagnose", str(_huge_bundle(d)), "--out", str(d / "o")],
        2, "experiment.json: 17.0 MB, too large (the limit for a JSON, TOML or Modelica input file is 16 MB; "
           "raise it with MOTIONTWIN_MAX_TEXT_MB=18 if intended)"),
    "diagnose: a 17 MB plant Modelica file": (
        lambda d, f: ["diagnose", str(_huge_plant_bundle(d)), "--out", str(d / "o")],
        2, "plant.mo: 17.0 MB, too large (the limit for a JSON, TOML or Modelica input file is 16 MB"),
    "diagnose: experiment.json is a folder": (
        lambda d, f: ["diagnose", str((d / "b" / "experiment.json").mkdir(parents=True) or d / "b"), "--out",
                      str(d / "o")],
        2, "experiment.json: is a folder, expected a file"),
    "run: an FMU path that is a folder": (
        lambda d, f: ["run", str(_system(d, d)), "--out", str(d / "o.csv")],
        1, "FMU 'pi': a folder, not an FMU file"),
    "sweep: colliding sanitised case names": (
        lambda d, f: ["sweep", str(_sweep(d, f, '[[case]]\nname = "a b"\n[[case]]\nname = "a_b"\n')),
                      "--out", str(d / "o")],
        1, "case name 'a_b' occurs twice"),
    "sweep: a 300-character case name": (
        lambda d, f: ["sweep", str(_sweep(d, f, f'[[case]]\nname = "{"k" * 300}"\n')), "--out", str(d / "o")],
        1, "has 300 characters, more than 200"),
}


def _one_line(argv: list[str], capsys) -> tuple[int, str]:
    code = main(argv)
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert "Traceback" not in captured.err, captured.err
    assert len(err.splitlines()) == 1, err
    return code, err


@pytest.mark.parametrize("name", list(CASES))
def test_bad_input_gives_one_message(name: str, plant_fmu: Path, tmp_path: Path, capsys) -> None:
    build, code, fragment = CASES[name]
    argv = build(tmp_path, plant_fmu)
    got, err = _one_line(argv + (["--quiet"] if argv[0] == "diagnose" else []), capsys)
    assert (got, fragment in err) == (code, True), err
    assert "root:" not in err and "np.float64" not in err
    assert not (tmp_path / "o").exists() and not (tmp_path / "o.csv").exists()


@pytest.mark.parametrize("variable, argv, fragment", [
    ("MOTIONTWIN_MAX_TEXT_MB", ["excite", str(EXPERIMENT), "--out", "x.csv"],
     "MB, too large (the limit for a JSON, TOML or Modelica input file is 0.0001 MB; raise it with "
     "MOTIONTWIN_MAX_TEXT_MB=1 if intended)"),
    ("MOTIONTWIN_MAX_MEMORY_MB", ["excite", str(EXPERIMENT), "--out", "x.csv"],
     "swept_sine_80_500.toml: 4400 samples x 2 columns needs about 0.000563 GB of memory, more than the limit of "
     "1e-07 GB; raise it with MOTIONTWIN_MAX_MEMORY_MB=2 if intended"),
])
def test_limits_are_overridable_and_named(variable, argv, fragment, tmp_path, monkeypatch, capsys) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv(variable, "0.0001")
    code, err = _one_line(argv, capsys)
    assert code == 1 and fragment in err, err
    monkeypatch.setenv(variable, "1e4")
    assert main(argv) == 0
    assert (tmp_path / "x.csv").is_file()


def test_diagnose_refuses_before_the_analysis_when_its_staging_folder_is_not_writable(world_readable_dir,
                                                                                       capsys) -> None:
    root = world_readable_dir
    parent = root / "locked"
    (parent / "out").mkdir(parents=True)
    os.chmod(parent / "out", 0o777)
    os.chmod(parent, 0o555)
    try:
        with _unprivileged():
            code, err = _one_line(["diagnose", str(root / "missing"), "--out", str(parent / "out")], capsys)
    finally:
        os.chmod(parent, 0o755)
    assert code == 1 and f"--out (staged in the folder above) {parent}: folder {parent} is not writable" in err, err


# -- fuzz: the JSON, TOML and CSV readers answer one error line for any bytes ---------------------------------

def _readers():
    from motiontwin.fmus.limits import load_json
    from motiontwin.harness.experiment import load_experiment
    from motiontwin.harness.recording import read_recording
    from motiontwin.harness.labdata import read_lab_file
    from motiontwin.harness.system import load_system
    from motiontwin.ident.controller import load_controller
    from motiontwin.ident.startvalues import read_values_file

    def with_sidecar(sidecar: Path):
        """A good recording CSV read with ``sidecar`` as its JSON sidecar."""
        sidecar.with_suffix(".csv").write_text("time,q\n0,1\n0.001,2\n")
        return read_recording(sidecar.with_suffix(".csv"))

    return {"values.json": read_values_file, "any.json": load_json, "controller.json": load_controller,
            "system.toml": load_system, "experiment.toml": load_experiment, "recording.csv": read_recording,
            "lab.csv": read_lab_file, "sidecar.json": with_sidecar}


SEEDS = [NESTED.encode(), b"{" * 5000, b"a = " + b"[" * 5000, b"time,q\n0,1\n0,1e999\n", b"time\n" + b"0\n" * 3,
         b'{"parameters": {"m": "big"}}', b'{"parameters": [[1]], "version": "2"}', b"[fmus.a]\npath = 3\n",
         b"\xff\xfe", b"\r0", b'"time\r",q\n0,1\n']


def _read_one(reader: str, content: bytes | str, folder: Path) -> None:
    """Read ``content`` with ``reader``: it is read, or refused with a message naming the file."""
    path = folder / reader
    path.write_bytes(content.encode() if isinstance(content, str) else content)
    try:
        _readers()[reader](path)
    except (ValueError, KeyError, OSError) as exc:   # the errors motiontwin.cli.main turns into one line
        message = str(exc)
        assert str(path.with_suffix("")) in message, message   # the file (a sidecar's CSV for the sidecar)
        assert "Traceback" not in message


@pytest.mark.parametrize("content", SEEDS)
def test_readers_on_the_known_hostile_inputs(content: bytes, tmp_path: Path) -> None:
    for reader in _readers():
        _read_one(reader, content, tmp_path)


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(content=st.one_of(st.sampled_from(SEEDS), st.binary(max_size=300),
                         st.text(alphabet='[]{}=",.:0123456789abtimeq\n\r -', max_size=300)),
       reader=st.sampled_from(sorted(_readers())))
def test_readers_never_raise_anything_but_their_error(content: bytes | str, reader: str, tmp_path: Path) -> None:
    _read_one(reader, content, tmp_path)


SYSTEM = {"base_step": 1e-4, "stop_time": 0.3, "fmus": {"pi": {"path": "a.fmu", "parameters": {"Kp": 1.0}},
                                                        "plant": {"path": "b.fmu"}},
          "inputs": {"r": {"unit": "m"}, "u_ext": {"unit": "N", "default": 0.0}},
          "connections": [{"from": ["input.r", "plant.q"], "gains": [1.0, -1.0], "to": "pi.e"},
                          {"from": ["pi.y", "input.u_ext"], "to": "plant.u"}],
          "log": [{"signals": ["plant.q", "pi.y"]}], "order": ["pi", "plant"]}
VALUES = [None, True, 0, -1, 1e300, math.nan, math.inf, "x", "", "input.r", [], ["x"], [1, "a"], {}, {"a": 1},
          [{"a": 1}], [[1]]]


def _places(doc, prefix: tuple = ()):
    """Every key path of a nested dict/list document."""
    items = doc.items() if isinstance(doc, dict) else enumerate(doc) if isinstance(doc, list) else ()
    for key, value in items:
        yield prefix + (key,)
        yield from _places(value, prefix + (key,))


@settings(max_examples=150, deadline=None)
@given(edits=st.lists(st.tuples(st.sampled_from(list(_places(SYSTEM))), st.sampled_from(VALUES)), min_size=1,
                      max_size=3))
def test_system_file_structure_errors_name_the_file(edits) -> None:
    """A system document with values of any type anywhere: accepted, or SystemFileError naming the file."""
    from motiontwin.harness.system import SystemFileError, system_from_dict

    doc = copy.deepcopy(SYSTEM)
    for place, value in edits:   # an earlier edit may have replaced the container: then this one is skipped
        with contextlib.suppress(KeyError, IndexError, TypeError):
            target = doc
            for key in place[:-1]:
                target = target[key]
            target[place[-1]] = copy.deepcopy(value)
    try:
        system_from_dict(doc, source=Path("/bundle/s.toml"))
    except SystemFileError as exc:
        assert str(exc).startswith("/bundle/s.toml"), exc
