"""Every subcommand against a read-only target, a file where a folder is expected and a non-zip .fmu: exit code 1,
one line on stderr naming the path, no traceback, nothing written and earlier results untouched.

The inputs are chosen so that the failure comes before any build or simulation (each call takes milliseconds).
As root, permissions do not stop writes, so the read-only case runs with the effective user ``nobody``.
"""
from __future__ import annotations

import contextlib
import os
import pwd
import shutil
import stat
import tempfile
import zipfile
from pathlib import Path
from typing import Iterator

import pytest

from motiontwin.cli import main
from tests.test_master import PI_LOOP

EXPERIMENT = Path(__file__).resolve().parents[1] / "harness" / "experiments" / "swept_sine_80_500.toml"


def _commands(root: Path, out_file: Path, out_folder: Path) -> dict[str, list[str]]:
    """argv of every subcommand writing ``out_file`` (file outputs) or ``out_folder`` (folder outputs)."""
    missing = str(root / "missing.csv")
    return {
        "build": ["build", "MotionTwin.Plants.LinearMotorJoint", "--out", str(out_folder)],
        "excite": ["excite", str(EXPERIMENT), "--out", str(out_file)],
        "run": ["run", str(root / "loop.toml"), "--out", str(out_file)],
        "sweep": ["sweep", str(root / "sweep.toml"), "--out", str(out_folder)],
        "regress --junit": ["regress", str(root / "suite.toml"), "--junit", str(out_file)],
        "regress --plots": ["regress", str(root / "suite.toml"), "--plots", str(out_folder)],
        "ssp": ["ssp", str(root / "loop.toml"), str(out_file)],
        "identify joint": ["identify", "joint", missing, "--f0", "1", "--cutoff", "10", "--out", str(out_file)],
        "identify frf": ["identify", "frf", missing, "--out", str(out_file)],
        "identify oe": ["identify", "oe", missing, "--class", "X", "--free", "m", "--out", str(out_file)],
        "identify hexapod": ["identify", "hexapod", missing, "--f0", "1", "--cutoff", "10", "--out", str(out_file)],
        "identify projection": ["identify", "projection", missing, "--out", str(out_file)],
        "design-excitation": ["design-excitation", "joint", "--f0", "1", "--harmonics", "3", "--q-range", "0.1",
                              "--v-max", "1", "--a-max", "10", "--out", str(out_file)],
        "writeback": ["writeback", str(root / "good.fmu"), "--set", "m=1", "--out", str(out_file)],
        "tune": ["tune", "--out", str(out_file)],
        "tune --plots": ["tune", "--plots", str(out_folder)],
        "compare": ["compare", "--out", str(out_folder)],
        "diagnose": ["diagnose", str(root), "--out", str(out_folder)],
        "demo": ["demo", "--out", str(out_folder)],
    }


def _inputs(root: Path, fmu: Path) -> None:
    """A system, sweep and suite file using ``fmu`` as both FMUs, and a zip named good.fmu."""
    (root / "loop.toml").write_text(PI_LOOP.format(pi=fmu, plant=fmu))
    (root / "sweep.toml").write_text('system = "loop.toml"\n')
    (root / "suite.toml").write_text('[[case]]\nname = "a"\nsystem = "loop.toml"\nreference = "ref.csv"\n')
    shutil.make_archive(str(root / "good"), "zip", root_dir=root, base_dir="sweep.toml")
    (root / "good.zip").rename(root / "good.fmu")


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _check(argv: list[str], capsys, expected: str, code: int = 1) -> None:
    """One line on stderr naming the fault, exit ``code`` (``regress`` documents 2 for an unusable suite)."""
    returned = main(argv)
    err = capsys.readouterr().err
    assert returned == code, (argv, err)
    assert "Traceback" not in err, err
    assert len(err.strip().splitlines()) == 1, err
    assert expected in err, (argv, err)


@contextlib.contextmanager
def _unprivileged() -> Iterator[None]:
    """Run as the user ``nobody`` when root (root writes into read-only folders)."""
    if os.geteuid() != 0:
        yield
        return
    nobody = pwd.getpwnam("nobody")
    os.setegid(nobody.pw_gid)
    os.seteuid(nobody.pw_uid)
    try:
        yield
    finally:
        os.seteuid(0)
        os.setegid(0)


@pytest.fixture
def world_readable_dir() -> Iterator[Path]:
    """A folder the user ``nobody`` can read (pytest's tmp_path is private to its owner)."""
    root = Path(tempfile.mkdtemp(prefix="motiontwin-cli-errors-"))
    root.chmod(0o755)
    try:
        yield root
    finally:
        for path in [root, *root.rglob("*")]:
            if path.is_dir():
                path.chmod(0o755)
        shutil.rmtree(root)


def test_read_only_target_is_one_line_and_leaves_earlier_results(world_readable_dir, capsys):
    root = world_readable_dir
    _inputs(root, root / "missing.fmu")
    locked = root / "locked"
    locked.mkdir()
    (locked / "earlier.csv").write_text("time,q\n0,1\n")
    before = _snapshot(locked)
    locked.chmod(stat.S_IRUSR | stat.S_IXUSR | stat.S_IRGRP | stat.S_IXGRP | stat.S_IROTH | stat.S_IXOTH)
    for name, argv in _commands(root, locked / "new.csv", locked / "new").items():
        with _unprivileged():
            _check(argv, capsys, str(locked))
    locked.chmod(0o755)
    assert _snapshot(locked) == before


def test_file_where_a_folder_is_expected(tmp_path, capsys):
    _inputs(tmp_path, tmp_path / "missing.fmu")
    blocker = tmp_path / "blocker"
    blocker.write_text("a file\n")
    for name, argv in _commands(tmp_path, blocker / "new.csv", blocker).items():
        _check(argv, capsys, str(blocker))
    assert blocker.read_text() == "a file\n"
    for name, argv in _commands(tmp_path, blocker / "sub" / "new.csv", blocker / "sub").items():
        _check(argv, capsys, str(blocker))


def test_non_zip_fmu_names_the_file(tmp_path, capsys):
    bad = tmp_path / "bad.fmu"
    bad.write_text("not a zip archive\n")
    _inputs(tmp_path, bad)
    out = tmp_path / "out"
    argvs = {
        "run": ["run", str(tmp_path / "loop.toml"), "--out", str(tmp_path / "r.csv")],
        "sweep": ["sweep", str(tmp_path / "sweep.toml"), "--out", str(out)],
        "ssp": ["ssp", str(tmp_path / "loop.toml"), str(tmp_path / "loop.ssp"), "--drop-external-in-sums"],
        "writeback": ["writeback", str(bad), "--set", "m=1", "--out", str(tmp_path / "new.fmu")],
        "tune --fmu": ["tune", "--fmu", str(bad), "--fmu-out", str(tmp_path / "new.fmu")],
        "tune --plant-fmu": ["tune", "--plant-fmu", str(bad)],
    }
    for name, argv in argvs.items():
        _check(argv, capsys, f"{bad}: not an FMU (not a zip archive)")
    # a zip without modelDescription.xml is named as such (was: KeyError 'modelDescription.xml')
    _check(argvs["writeback"][:1] + [str(tmp_path / "good.fmu")] + argvs["writeback"][2:], capsys,
           "holds no modelDescription.xml")
    broken = tmp_path / "broken.fmu"   # a zip whose modelDescription.xml is cut off
    with zipfile.ZipFile(broken, "w") as archive:
        archive.writestr("modelDescription.xml", '<fmiModelDescription fmiVersion="2.0"><Broken')
    for argv in (["writeback", str(broken), "--set", "m=1", "--out", str(tmp_path / "new.fmu")],
                 ["tune", "--plant-fmu", str(broken)]):
        _check(argv, capsys, f"{broken}: malformed modelDescription.xml")
    _inputs(tmp_path, broken)
    _check(argvs["run"], capsys, f"{broken}: malformed modelDescription.xml")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.fmu", "broken.fmu", "good.fmu", "loop.toml",
                                                           "suite.toml", "sweep.toml"]


def test_interrupt_is_exit_130_and_one_line(tmp_path, capsys, monkeypatch):
    import motiontwin.harness.experiment as experiment

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(experiment, "load_experiment", interrupted)
    out = tmp_path / "x.csv"
    assert main(["excite", str(EXPERIMENT), "--out", str(out)]) == 130
    err = capsys.readouterr().err
    assert "interrupted" in err and "Traceback" not in err
    assert not out.exists()


def test_compare_reads_the_design_files_before_building(tmp_path, capsys):
    out = tmp_path / "out"
    _check(["compare", "--design", str(tmp_path / "nope.json"), "--out", str(out)], capsys,
           f"{tmp_path / 'nope.json'}: not found")
    bad = tmp_path / "bad.json"
    bad.write_text('{"parameters": {"Kp": 1.0}}\n')
    _check(["compare", "--design", str(bad), "--out", str(out)], capsys, f"{bad}: field 'parameters' lacks")
    assert not out.exists()


@pytest.mark.parametrize("argv, message", [
    (["tune", "--gm", "nan"], "--gm nan: must be a finite number"),
    (["tune", "--tau-max", "nan"], "--tau-max nan: must be a finite number > 0"),
    (["tune", "--ts", "0"], "--ts 0.0: must be a finite number > 0"),
    (["tune", "--gain-spread", "1.5"], "--gain-spread 1.5: must be below 1"),
    (["tune", "--plant", "omega=1000,omega_bar=2000"],
     "field 'omega' = 1000.0 rad/s must be above 'omega_bar' = 2000.0 rad/s"),
    (["tune", "--plant", "K=nan"], "field 'K' = 'nan' is not a finite number"),
    (["sweep", "s.toml", "--workers", "0", "--out", "x"], "workers: expected a positive number of worker processes"),
    (["compare", "--out", "cmp", "--stop-time", "nan"], "--stop-time nan: must be a finite number > 0"),
    (["compare", "--out", "cmp", "--stop-time", "1e300"], "--stop-time = 1e+300 s gives 2e+303 steps of 0.0005 s, "
                                                          "more than the limit of 1e+08"),
    (["design-excitation", "joint", "--f0", "1", "--harmonics", "3", "--q-range", "0.1", "--v-max", "1",
      "--a-max", "10", "--sample-time", "1e-300", "--out", "d.toml"], "gives 1e+301 steps of 1e-300 s"),
])
def test_bad_options_name_the_option(argv: list[str], message: str, capsys, tmp_path, monkeypatch) -> None:
    from motiontwin.ident import tuning

    monkeypatch.chdir(tmp_path)
    (tmp_path / "s.toml").write_text('system = "loop.toml"\n')
    _inputs(tmp_path, tmp_path / "missing.fmu")
    assert tuning.TuningSpec().gm_min_db == 7.0
    with pytest.raises(tuning.TuningError, match=r"gm_min_db \(--gm\) must be a finite number"):
        tuning.TuningSpec(gm_min_db=float("nan"))
    _check(argv, capsys, message)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["good.fmu", "loop.toml", "s.toml", "suite.toml",
                                                           "sweep.toml"]


@pytest.mark.parametrize("field, text, message", [
    ("amplitude", "amplitude = nan", "field 'excitation.amplitude' must be a finite number, got nan"),
    ("duration", "duration = 1e300", "field 'duration' = 1e+300 s gives 1e+304 steps of 0.0001 s, more than the "
                                     "limit of 1e+08"),
])
def test_experiment_fields_are_named(tmp_path, capsys, field, text, message) -> None:
    experiment = tmp_path / "e.toml"
    base = "sample_time = 1e-4\nduration = 0.3\n[excitation]\nkind = \"step\"\nt_step = 0.01\namplitude = 1.0\n"
    experiment.write_text(base.replace("duration = 0.3", text) if field == "duration"
                          else base.replace("amplitude = 1.0", text))
    _check(["excite", str(experiment), "--out", str(tmp_path / "x.csv")], capsys, f"{experiment}: {message}")
    assert not (tmp_path / "x.csv").exists()


def test_system_stop_time_beyond_the_limit_names_the_field(tmp_path, capsys) -> None:
    _inputs(tmp_path, tmp_path / "missing.fmu")
    system = tmp_path / "loop.toml"
    system.write_text(system.read_text().replace("stop_time = 0.3", "stop_time = 1e300"))
    _check(["run", str(system), "--out", str(tmp_path / "x.csv")], capsys,
           "stop_time: 1e+300 s gives 1e+304 steps of 0.0001 s, more than the limit of 1e+08")


def test_binary_input_files_are_named(tmp_path, capsys) -> None:
    junk = tmp_path / "junk.toml"
    junk.write_bytes(b"\x00\xff\xfe not text")
    for argv in (["excite", str(junk), "--out", str(tmp_path / "o.csv")],
                 ["run", str(junk), "--out", str(tmp_path / "o.csv")],
                 ["sweep", str(junk), "--out", str(tmp_path / "o")],
                 ["ssp", str(junk), str(tmp_path / "o.ssp")],
                 ["compare", "--design", str(junk), "--out", str(tmp_path / "o")]):
        _check(argv, capsys, f"{junk}: not UTF-8 text (byte 1: invalid start byte)")
    _check(["regress", str(junk)], capsys, f"{junk}: not UTF-8 text (byte 1: invalid start byte)", code=2)
    model = tmp_path / "junk.mo"
    model.write_bytes(junk.read_bytes())
    _check(["build", "Foo.Bar", "--modelica", str(model), "--out", str(tmp_path / "o")], capsys,
           f"{model}: not UTF-8 text (byte 1: invalid start byte)")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["junk.mo", "junk.toml"]


def test_out_into_a_missing_folder_names_the_folder_not_a_temporary_file(tmp_path, capsys) -> None:
    missing = tmp_path / "missing"
    _check(["excite", str(EXPERIMENT), "--out", str(missing / "x.csv")], capsys,
           f"{missing}: folder does not exist; create it first or choose another path")
    assert not missing.exists()


def test_plant_fmu_start_values_must_be_finite() -> None:
    from motiontwin.cli.arguments import name_values

    assert name_values("m=1.5, d=2", "--plant #1") == {"m": 1.5, "d": 2.0}
    with pytest.raises(ValueError, match=r"--plant #2 'd=2,m=nan': field 'm' = 'nan' is not a finite number"):
        name_values("d=2,m=nan", "--plant #2")
