"""Fixtures shared by the survey tests."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from survey.cli.main import main


@pytest.fixture(scope="session")
def tbm_mesh(tmp_path_factory):
    """make(edge_length_m) -> path of a 'tbm' preset tunnel written by the CLI (once per
    edge length and session; tests must not modify it)."""
    made = {}

    def make(edge_length_m: float):
        if edge_length_m not in made:
            out = tmp_path_factory.mktemp("tbm") / "tbm.ply"
            assert main(["tunnel", "-o", str(out), "--preset", "tbm", "--edge-length",
                         str(edge_length_m), "--quiet"]) == 0
            made[edge_length_m] = out
        return made[edge_length_m]

    return make


@pytest.fixture(scope="session")
def tbm_20k(tmp_path_factory):
    """A 100 m 'tbm' tunnel of ~20k triangles with its JSON (alignment on x), once per
    session (tests must not modify it)."""
    out = tmp_path_factory.mktemp("tbm20k") / "tbm.ply"
    assert main(["tunnel", "--preset", "tbm", "--triangles", "20000", "-o", str(out),
                 "--quiet"]) == 0
    return out


CHECKER = Path(__file__).parent / "export" / "sdf" / "sdf_check.cpp"


@pytest.fixture(scope="session")
def sdf_check(tmp_path_factory):
    """The checker compiled once against libsdformat (skipped, with the reason, when
    the library or a compiler is missing)."""
    if not shutil.which("g++") or not shutil.which("pkg-config"):
        pytest.skip("g++ or pkg-config not found: cannot build the SDFormat checker")
    flags = subprocess.run(["pkg-config", "--cflags", "--libs", "sdformat12"],
                           capture_output=True, text=True)
    if flags.returncode != 0:
        pytest.skip("libsdformat-dev (SDFormat 12) not installed: apt-get install "
                    "libsdformat-dev (.ci/run does)")
    exe = tmp_path_factory.mktemp("sdf") / "sdf_check"
    r = subprocess.run(["g++", "-std=c++17", "-O1", str(CHECKER), "-o", str(exe),
                        *flags.stdout.split()], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    return exe
