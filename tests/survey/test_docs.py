"""The README's generator example runs as written and produces what it says."""

from __future__ import annotations

from pathlib import Path

import numpy as np

README = Path(__file__).resolve().parents[2] / "README.md"


def test_readme_generator_example(tmp_path, monkeypatch):
    text = README.read_text()
    code = text.split("## Generated tunnels")[1].split("```python")[1].split("```")[0]
    monkeypatch.chdir(tmp_path)
    ns: dict = {}
    exec(compile(code, "README.md", "exec"), ns)
    tun = ns["tun"]
    assert {"cable", "niche", "drainage", "wet_floor", "prism"} <= set(tun.metadata["face_counts"])
    assert (tmp_path / "tunnel.json").is_file() and (tmp_path / "epoch2.ply").is_file()
    assert tun.vertices[:, 0].min() > 450_000 and np.isfinite(tun.vertices).all()


def test_readme_python_api_example(tmp_path, monkeypatch, capsys):
    text = README.read_text()
    code = text.split("## The Python API in ten lines")[1].split("```python")[1].split("```")[0]
    assert len([ln for ln in code.strip().splitlines() if ln.strip()]) <= 14
    monkeypatch.chdir(tmp_path)
    ns: dict = {}
    exec(compile(code, "README.md", "exec"), ns)
    # A station in the middle of a smooth bored tunnel: the points lie on the mesh to
    # within the scanner's range noise (sub-mm at these ranges) and the jitter.
    assert len(ns["pts"]) > 100_000
    assert abs(ns["d"].mean()) < 0.001 and ns["d"].std() < 0.003
    assert "points, noise" in capsys.readouterr().out


def test_readme_figure_exists():
    import re

    for link in re.findall(r"!\[[^\]]*\]\(([^)]+)\)", README.read_text()):
        p = README.parent / link
        assert p.is_file() and p.read_bytes()[:4] == b"\x89PNG", link
