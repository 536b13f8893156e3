"""Atomic writes onto another file system (a tmpfs mounted for the test) and onto a full one.

``build --out MNT`` and a diagnosis published into MNT failed with "Invalid cross-device link" when the staging
folder sat on the parent's file system; a full disk gave ``[Errno 28]`` without a path. Mounting needs root
(or CAP_SYS_ADMIN); elsewhere these tests are skipped with that reason.
"""
from __future__ import annotations

import errno
import os
import subprocess
from pathlib import Path
from typing import Iterator

import pytest

from motiontwin.cli import main
from motiontwin.fmus.files import atomic_write_texts, move_file
from tests.test_cli_errors import EXPERIMENT, world_readable_dir  # noqa: F401 (a fixture)


def _mount(point: Path, size: str) -> Iterator[Path]:
    point.mkdir()
    proc = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(point)],
                          capture_output=True, text=True)
    if proc.returncode != 0:
        pytest.skip(f"mounting a tmpfs is not permitted here: {proc.stderr.strip() or proc.returncode}")
    try:
        yield point
    finally:
        subprocess.run(["umount", str(point)], check=True)


@pytest.fixture
def mount_point(tmp_path) -> Iterator[Path]:
    """An empty tmpfs (another file system than ``tmp_path``) mounted at ``tmp_path / "mnt"``."""
    yield from _mount(tmp_path / "mnt", "64m")


@pytest.fixture
def full_mount(tmp_path) -> Iterator[Path]:
    """A 1 MB tmpfs filled to the last byte."""
    for point in _mount(tmp_path / "full", "1m"):
        filler = point / "filler"
        with open(filler, "wb") as handle, pytest.raises(OSError) as caught:
            while True:
                handle.write(b"\0" * 65536)
                handle.flush()
        assert caught.value.errno == errno.ENOSPC
        yield point


def test_mount_point_is_another_file_system(mount_point, tmp_path) -> None:
    assert os.stat(mount_point).st_dev != os.stat(tmp_path).st_dev


def test_move_across_file_systems_copies_then_renames(mount_point, tmp_path) -> None:
    src = tmp_path / "staged.bin"
    src.write_bytes(b"payload")
    with pytest.raises(OSError) as caught:
        os.replace(src, mount_point / "x.bin")   # what the writers did before
    assert caught.value.errno == errno.EXDEV
    move_file(src, mount_point / "x.bin")
    assert (mount_point / "x.bin").read_bytes() == b"payload"
    assert not src.exists()
    assert sorted(p.name for p in mount_point.iterdir()) == ["x.bin"]


def test_diagnosis_publish_into_a_mount_point(mount_point, tmp_path) -> None:
    from motiontwin.ident.diagnosis.pipeline import _publish

    staging = tmp_path / "staging"
    (staging / "augmented_model").mkdir(parents=True)
    (staging / "diagnosis.json").write_text("{}\n")
    (staging / "augmented_model" / "Plant.mo").write_text("model Plant end Plant;\n")
    _publish(staging, mount_point)
    assert (mount_point / "diagnosis.json").read_text() == "{}\n"
    assert (mount_point / "augmented_model" / "Plant.mo").read_text() == "model Plant end Plant;\n"
    assert not staging.exists()


def test_build_into_a_mount_point(mount_point, capsys) -> None:
    assert main(["build", "MotionTwin.Plants.LinearMotorJoint", "--fmi", "2.0", "--out", str(mount_point)]) == 0
    fmu = mount_point / "fmi2" / "LinearMotorJoint.fmu"
    assert capsys.readouterr().out.split() == [str(fmu)]
    assert fmu.stat().st_size > 10_000
    assert [p.name for p in mount_point.rglob("*") if p.name.startswith(".")] == []


def test_full_disk_names_the_file_and_keeps_the_earlier_one(full_mount) -> None:
    target = full_mount / "x.csv"
    with pytest.raises(OSError) as caught:
        atomic_write_texts({target: "a" * 100_000})
    assert caught.value.errno == errno.ENOSPC and caught.value.filename == str(target)
    assert not target.exists()
    assert sorted(p.name for p in full_mount.iterdir()) == ["filler"]


@pytest.mark.parametrize("command", ["excite", "build", "writeback", "import"])
def test_full_disk_is_one_line_naming_the_output(command, full_mount, tmp_path, capsys) -> None:
    import numpy as np
    import scipy.io

    from motiontwin.fmus import build

    fmu = build.build(["MotionTwin.Plants.LinearMotorJoint"], out_dir=tmp_path / "fmus", fmi_versions=("2.0",),
                      workers=1)[0].path
    scipy.io.savemat(tmp_path / "lab.mat", {"time": np.arange(100) * 1e-3, "q": np.zeros(100)})
    argv, named = {
        "excite": (["excite", str(EXPERIMENT), "--out", str(full_mount / "x.csv")], full_mount / "x.csv"),
        "build": (["build", "MotionTwin.Plants.LinearMotorJoint", "--fmi", "2.0", "--out", str(full_mount / "f")],
                  full_mount / "f"),
        "writeback": (["writeback", str(fmu), "--set", "m=3", "--out", str(full_mount / "w.fmu")],
                      full_mount / "w.fmu"),
        "import": (["import", str(tmp_path / "lab.mat"), "--out", str(full_mount / "lab.csv")],
                   full_mount / "lab.csv"),
    }[command]
    capsys.readouterr()
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert err == f"motiontwin {command}: {named}: no space left on the device; free space and run again\n"
    assert sorted(p.name for p in full_mount.iterdir()) == ["filler"]


def test_staging_goes_inside_an_output_folder_whose_parent_is_read_only(world_readable_dir) -> None:
    from motiontwin.fmus.files import staging_folder
    from tests.test_cli_errors import _unprivileged

    parent = world_readable_dir / "ro"
    out = parent / "out"
    out.mkdir(parents=True)
    out.chmod(0o777)
    parent.chmod(0o555)
    try:
        with _unprivileged():
            with staging_folder(out) as staging:
                assert staging.parent == out and staging.name.startswith(".out-staging-")
                (staging / "a.fmu").write_bytes(b"fmu")
                move_file(staging / "a.fmu", out / "a.fmu")
            assert [p.name for p in out.iterdir()] == ["a.fmu"]
            with staging_folder(out / "new") as staging:   # the usual case: beside the folder
                assert staging.parent == out and staging.name.startswith(".new-staging-")
    finally:
        parent.chmod(0o755)
