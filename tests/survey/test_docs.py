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
