"""The ``tunnelsim`` command: version, info, one-line errors with exit status 2."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numba
import pytest

from survey.cli import main


def test_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("tunnelsim ") and out.strip().split()[1][0].isdigit()


def test_info_reports_threading(capsys):
    assert main(["info"]) == 0
    out = capsys.readouterr().out
    assert f"numba {numba.__version__}" in out
    layer = [line for line in out.splitlines() if line.startswith("numba threading layer")]
    assert layer and layer[0].split(": ")[1] in {"tbb", "omp", "workqueue"}
    assert f"numba threads: {numba.get_num_threads()} of" in out


def test_bad_command_is_one_line_exit_2(capsys):
    assert main(["frobnicate"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "invalid choice" in err


def test_console_script_installed():
    beside = Path(sys.executable).with_name("tunnelsim")
    exe = str(beside) if beside.exists() else shutil.which("tunnelsim")
    if exe is None:
        pytest.skip("tunnelsim console script not on PATH (package not installed)")
    res = subprocess.run([exe, "nope"], capture_output=True, text=True)
    assert res.returncode == 2
    assert len(res.stderr.strip().splitlines()) == 1 and "Traceback" not in res.stderr


def test_import_compiles_nothing():
    """The first import must not compile (or load) kernels: Numba compiles lazily."""
    code = ("import raytrace, survey.cli\n"
            "from raytrace._kernels import build, cubemap, traverse\n"
            "fs = [build.build_top, build._grow_pending, build.triangle_setup, "
            "traverse.closest_hit, traverse.any_hit, cubemap.closest_hit_view]\n"
            "print(sum(len(f.signatures) for f in fs))\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert res.stdout.strip() == "0"
