"""Every Python example in the README runs as written, in a fresh folder, and produces
what the text around it says. A new example without a check here fails the suite."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from tests.naive import naive_cast

README = Path(__file__).resolve().parents[1] / "README.md"


def _examples() -> dict[str, str]:
    """{section heading: its Python code} for every ```python block."""
    out, section = {}, None
    for part in re.split(r"^(## .*)$", README.read_text(), flags=re.M):
        if part.startswith("## "):
            section = part[3:].strip()
            continue
        for i, code in enumerate(re.findall(r"```python\n(.*?)```", part, flags=re.S)):
            out[section if i == 0 else f"{section} ({i + 1})"] = code
    return out


EXAMPLES = _examples()


def _run(name, tmp_path, monkeypatch) -> dict:
    monkeypatch.chdir(tmp_path)
    ns: dict = {}
    exec(compile(EXAMPLES[name], f"README.md: {name}", "exec"), ns)
    return ns


def check_python_api(ns, out, tmp_path):
    # A station in the middle of a smooth bored tunnel: the points lie on the mesh to
    # within the scanner's range noise (sub-mm at these ranges) and the jitter.
    assert len(ns["pts"]) > 100_000
    assert abs(ns["d"].mean()) < 0.001 and ns["d"].std() < 0.003
    assert "points, noise" in out


def check_raycasting(ns, out, tmp_path):
    tun, d = ns["tun"], ns["directions"]
    ref = naive_cast(tun.vertices, tun.faces, np.array([[50.0, 0.0, 0.0]]), d)
    ref_t = ref[0] if isinstance(ref, tuple) else ref.t
    hits = ns["hits"]
    np.testing.assert_allclose(hits.t[np.isfinite(ref_t)], ref_t[np.isfinite(ref_t)],
                               rtol=0, atol=1e-9)
    assert (np.isfinite(hits.t) == np.isfinite(ref_t)).all()
    unit = d / np.linalg.norm(d, axis=1, keepdims=True)
    assert (ns["near"] == (hits.t <= 2.0)).all()
    cos = np.abs(np.einsum("ij,ij->i", unit, hits.normals))[hits.hit]
    np.testing.assert_allclose(np.cos(hits.incidence_rad[hits.hit]), cos, atol=1e-9)
    assert (tmp_path / "tunnel.bvh.npz").is_file() and "rays hit" in out


def check_generated(ns, out, tmp_path):
    tun = ns["tun"]
    assert {"cable", "niche", "drainage", "wet_floor", "prism"} <= \
        set(tun.metadata["face_counts"])
    assert (tmp_path / "tunnel.json").is_file() and (tmp_path / "epoch2.ply").is_file()
    assert tun.vertices[:, 0].min() > 450_000 and np.isfinite(tun.vertices).all()


def check_scanners(ns, out, tmp_path):
    import laspy

    st = laspy.read(tmp_path / "station.laz")
    assert len(st.points) > 10_000
    # Every station point lies within the scanner's range of the station.
    r = np.linalg.norm(np.stack([st.x - 60.0, st.y, st.z - 1.5], 1), axis=1)
    assert r.max() < 200.0 and r.min() > 0.3
    traj = ns["traj"]
    assert traj.times[0] == 0.0 and abs(traj.times[-1] - 2.0) < 1e-9  # 4 m at 2 m/s
    dr = laspy.read(tmp_path / "drive.laz")
    assert len(dr.points) > 10_000
    assert dr.gps_time.min() >= 0.0 and dr.gps_time.max() <= 2.0
    assert "[" in out  # the first chunk's coordinates were printed


def check_helmert(ns, out, tmp_path):
    res, truth, source, target = ns["res"], ns["truth"], ns["source"], ns["target"]
    assert abs(res.scale_ppm - 20.0) < 3 * 0.002 / 50.0 * 1e6
    np.testing.assert_allclose(res.apply(source[0]), target[0], atol=0.01)
    np.testing.assert_allclose(res.apply(source), truth.apply(source), atol=0.005)
    assert "+proj=helmert" in out


def check_slam(ns, out, tmp_path):
    # GenZ-ICP tracks 8 m of the rock gallery (standing still 1 s at each end) to a few
    # cm; the evaluation is against the truth the drive was simulated on.
    err = ns["err"]
    assert abs(err.path_length_m - 8.0) < 0.05
    assert err.final_error_m < 0.1 and err.ate_rms_m < 0.1
    # 8 s: 1 s still, 6 s of trip (1 m/s² up to 2 m/s and down), 1 s still; 10 Hz.
    assert ns["res"].method == "genz-icp" and len(ns["res"].times) >= 75
    assert "final error" in out


CHECKS = {
    "The Python API in ten lines": check_python_api,
    "The ray-casting engine in ten lines": check_raycasting,
    "Generated tunnels": check_generated,
    "Simulated scanners": check_scanners,
    "Control points, Helmert adjustment, drift correction": check_helmert,
    "Real SLAM in the loop": check_slam,
}


def test_every_example_has_a_check():
    assert set(EXAMPLES) == set(CHECKS), "README Python examples and their checks differ"


@pytest.mark.parametrize("name", sorted(CHECKS))
def test_readme_example(name, tmp_path, monkeypatch, capsys):
    ns = _run(name, tmp_path, monkeypatch)
    CHECKS[name](ns, capsys.readouterr().out, tmp_path)


def test_readme_figures_exist():
    for link in re.findall(r"!\[[^\]]*\]\(([^)]+)\)", README.read_text()):
        p = README.parent / link
        assert p.is_file() and p.read_bytes()[:4] == b"\x89PNG", link


def _shell_commands() -> list[str]:
    """Every ``tunnelsim ...`` command line of the README's bash blocks, continuation
    lines joined and comments dropped."""
    lines = []
    for block in re.findall(r"```bash\n(.*?)```", README.read_text(), flags=re.S):
        for line in block.replace("\\\n", " ").splitlines():
            for part in re.split(r"&&|;", line.split(" #")[0]):
                part = part.split(">")[0].strip()            # no redirections
                if part.startswith("tunnelsim ") and not part[10:].startswith("-"):
                    lines.append(part)                       # not --version, --help
    return lines


SHELL = _shell_commands()


def test_the_readme_has_command_lines():
    assert len(SHELL) > 20


@pytest.mark.parametrize("line", SHELL)
def test_readme_command_lines_parse(line):
    """Each command line names a command and options it has, with values of the right
    kinds (the parser refuses anything else): README text that rots fails here."""
    import shlex

    from survey.cli.main import build_parser

    parser, commands = build_parser()
    argv = shlex.split(line)[1:]
    cmd = commands[argv[0]]
    args = cmd.parse(argv[1:])
    assert args is not None
