"""The public API type-checks: mypy (configured in pyproject.toml, Numba kernels
excluded) reports no error on raytrace, sensors and survey."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_mypy_passes_on_the_packages():
    pytest.importorskip("mypy", reason="mypy is in the test extra")
    run = subprocess.run([sys.executable, "-m", "mypy", "--no-error-summary"], cwd=ROOT,
                         capture_output=True, text=True)
    errors = [ln for ln in run.stdout.splitlines() if ": error:" in ln]
    assert run.returncode == 0 and not errors, "\n".join(errors or [run.stdout, run.stderr])


def test_mypy_catches_a_type_error(tmp_path):
    """The check above can fail: the same configuration flags a wrong call."""
    pytest.importorskip("mypy", reason="mypy is in the test extra")
    bad = tmp_path / "bad.py"
    bad.write_text("from raytrace.fileio import json_text\njson_text({}, indent='two')\n")
    run = subprocess.run([sys.executable, "-m", "mypy", "--config-file",
                          str(ROOT / "pyproject.toml"), str(bad)], cwd=ROOT,
                         capture_output=True, text=True)
    assert run.returncode != 0 and "indent" in run.stdout
