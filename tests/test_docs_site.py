"""The documentation site (docs/): it builds with Sphinx with warnings as errors, every
Python example in it runs as written and does what the text around it says, every
command line in it parses, and a broken link or anchor fails the build.

The Python examples run page by page, in order, in one namespace per page and a fresh
folder (a page is a notebook: later blocks use what earlier ones made). Each block has a
check below, keyed by (page, the heading above the block); a new example without a check
fails ``test_every_example_has_a_check``.
"""

from __future__ import annotations

import importlib.util
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.naive import naive_cast, naive_nearest, naive_point_mesh

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
SPHINX_PACKAGES = ("sphinx", "numpydoc", "myst_parser", "pydata_sphinx_theme")


def _pages() -> list[Path]:
    return sorted(p for p in DOCS.rglob("*.md")
                  if "_build" not in p.parts and "generated" not in p.parts)


def _blocks(page: Path, lang: str) -> list[tuple[str, str]]:
    """[(heading above the block, code)] for every ```lang block of a Markdown page, in
    order; a second block under one heading is "heading (2)"."""
    out: list[tuple[str, str]] = []
    heading: str = ""
    fence: str | None = None
    code: list[str] = []
    count: dict[str, int] = {}
    for line in page.read_text(encoding="utf-8").splitlines():
        stripped = line.strip()
        if fence is None:
            if stripped.startswith("```"):
                fence, code = stripped[3:].strip(), []
            elif re.match(r"^#{1,6} ", line):
                heading = line.lstrip("#").strip()
        elif stripped.startswith("```"):
            if fence == lang:
                count[heading] = count.get(heading, 0) + 1
                n = count[heading]
                out.append((heading if n == 1 else f"{heading} ({n})", "\n".join(code) + "\n"))
            fence = None
        else:
            code.append(line)
    return out


def _rel(page: Path) -> str:
    return page.relative_to(DOCS).as_posix()


EXAMPLES = {_rel(p): _blocks(p, "python") for p in _pages() if _blocks(p, "python")}


# --- checks: the user guide (the examples moved from the README) -----------------------

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


# --- checks: the tutorials --------------------------------------------------------------
# The tutorials' tunnel: 60 m straight along +x, a circle of radius 2.5 m whose lowest
# point is on the alignment, so its axis is the line y = 0, z = 2.5 (analytic truth).

def _radius_about_axis(xyz):
    xyz = np.asarray(xyz, dtype=np.float64)
    return np.hypot(xyz[:, 1], xyz[:, 2] - 2.5)


def check_tut_tunnel(ns, out, tmp_path):
    tun = ns["tun"]
    # Every vertex on the circle, up to the default millimetre roughness.
    r = _radius_about_axis(tun.vertices)
    assert np.abs(r - 2.5).max() < 0.02 and np.abs(r - 2.5).std() < 0.005
    assert abs(np.ptp(tun.vertices[:, 0]) - 60.0) < 1e-9
    assert sum(tun.metadata["face_counts"].values()) == len(tun.faces)
    assert "60.0 m" in out and "circle r=2.5 m" in out


def check_tut_rays(ns, out, tmp_path):
    hits, d = ns["hits"], ns["directions"]
    tun = ns["tun"]
    # Brute force: all rays against all triangles in float64.
    ref = naive_cast(tun.vertices, tun.faces, np.array([[30.0, 0.0, 2.5]]), d)
    ref_t = ref[0] if isinstance(ref, tuple) else ref.t
    assert np.isfinite(ref_t).all() and hits.hit.all()
    np.testing.assert_allclose(hits.t, ref_t, rtol=0, atol=1e-9)
    assert np.abs(hits.t - 2.5).max() < 0.02                 # the circle, rough to mm
    assert "360 of 360 rays hit" in out


def check_tut_epoch2(ns, out, tmp_path):
    # Convergence(20, 40, 0.01), taper 5 m: full 10 mm at chainage 25-35, none outside
    # 15-45 (the definition in survey.world.deformation; analytic).
    tun, epoch2 = ns["tun"], ns["epoch2"]
    moved = np.linalg.norm(epoch2.vertices - tun.vertices, axis=1)
    x = tun.vertices[:, 0]
    np.testing.assert_allclose(moved[np.abs(x - 30.0) < 5.0], 0.01, atol=1e-9)
    assert moved[(x < 15.0) | (x > 45.0)].max() == 0.0
    # Positive convergence moves the lining towards the axis.
    inner = _radius_about_axis(epoch2.vertices) - _radius_about_axis(tun.vertices)
    assert (inner[np.abs(x - 30.0) < 5.0] < -0.009).all()
    for name in ("epoch1.ply", "epoch1.json", "epoch2.ply", "epoch2.json"):
        assert (tmp_path / name).is_file()
    assert "moved 10.00 mm in the middle" in out and "0.00 mm before" in out


def check_tut_read_back(ns, out, tmp_path):
    back, tun = ns["back"], ns["tun"]
    assert np.array_equal(back.vertices, tun.vertices)
    assert np.array_equal(back.faces, tun.faces)
    assert abs(back.alignment.length_m - 60.0) < 1e-9 and "True 60.0" in out


def check_tut_world(ns, out, tmp_path):
    import trimesh

    scene, refl = ns["scene"], ns["reflectivity"]
    mesh = trimesh.load(tmp_path / "tunnel.ply", process=False)     # a third-party reader
    assert len(refl) == len(mesh.faces) and ((refl > 0) & (refl <= 1)).all()
    assert "zf_imager_5016" in out and "velodyne_vlp16" in out
    assert scene.n_triangles == len(mesh.faces)
    np.testing.assert_array_equal(scene.faces, mesh.faces)


def check_tut_station(ns, out, tmp_path):
    import laspy

    info, station = ns["info"], ns["station"]
    las = laspy.read(tmp_path / "station.laz")
    assert len(las.points) == info["points"] > 100_000
    assert info["points"] / info["pulses"] > 0.95       # only the portals let rays out
    xyz = np.stack([las.x, las.y, las.z], axis=1)
    # Every point on the lining: the analytic circle, within roughness + range noise.
    assert np.abs(_radius_about_axis(xyz) - 2.5).max() < 0.03
    assert f"{info['points']:,} points of {info['pulses']:,} pulses" in out
    del station


def check_tut_fields(ns, out, tmp_path):
    chunk, xyz, station = ns["chunk"], ns["xyz"], ns["station"]
    # The range field is the distance from the scanner to the point (independent
    # geometry); the noise is along the beam, so this holds to float rounding.
    np.testing.assert_allclose(chunk["range"], np.linalg.norm(xyz - station, axis=1),
                               rtol=0, atol=1e-6)
    assert {"x", "y", "z", "range", "intensity", "incidence", "time"} <= set(chunk.dtype.names)
    assert "range " in out and "incidence up to" in out


def check_tut_laz(ns, out, tmp_path):
    las, info = ns["las"], ns["info"]
    assert len(las.points) == info["points"]
    assert {"triangle", "channel", "column", "flag"} <= set(las.point_format.extra_dimension_names)
    # The hit triangle recorded per point is a real face of the mesh.
    assert 0 <= np.asarray(las["triangle"]).min() and \
        np.asarray(las["triangle"]).max() < ns["scene"].n_triangles
    # The file holds the run's points, in order, on its 0.1 mm grid.
    chunk = ns["chunk"]
    n = len(chunk)
    for axis in "xyz":
        np.testing.assert_allclose(np.asarray(las[axis])[:n], chunk[axis], rtol=0, atol=6e-5)
    assert str(info["points"]) in out


def check_tut_drive(ns, out, tmp_path):
    import laspy

    las = laspy.read(tmp_path / "drive.laz")
    info = ns["drive_info"]
    assert len(las.points) == info["points"] > 10_000
    assert las.gps_time.min() >= 0.0 and las.gps_time.max() <= 2.0 + 1e-9  # 4 m at 2 m/s
    xyz = np.stack([las.x, las.y, las.z], axis=1)
    # Every return is on the lining (the portals are 20 m away: the VLP-16's ±15° beams
    # reach them only beyond its range from the ends of the 4 m path).
    assert np.abs(_radius_about_axis(xyz) - 2.5).max() < 0.05
    assert "points in 2.0 s" in out


def check_tut_two_scans(ns, out, tmp_path):
    scan1, scan2 = ns["scan1"], ns["scan2"]
    assert scan1.dtype == np.float64 and scan1.shape[1] == 3 and len(scan2) > 100_000
    assert np.abs(_radius_about_axis(scan1) - 2.5).max() < 0.03
    assert f"{len(scan1):,} and {len(scan2):,} points" in out


def check_tut_c2m(ns, out, tmp_path):
    scan1, tun, c2m = ns["scan1"], ns["tun"], ns["c2m"]
    # Brute force on a sample: all points against all triangles, float64.
    sample = np.random.default_rng(0).choice(len(scan1), 200, replace=False)
    ref = naive_point_mesh(scan1[sample], tun.vertices, tun.faces)
    ref_d = ref[0] if isinstance(ref, tuple) else ref
    np.testing.assert_allclose(np.abs(c2m.distance[sample]), np.abs(ref_d), atol=1e-9)
    # The Z+F's range noise at 1-3 m is sub-millimetre (its spec file); no bias.
    assert abs(ns["stats"]["mean"]) < 1e-4 and ns["stats"]["std"] < 1e-3
    assert "C2M mean" in out


def check_tut_c2c(ns, out, tmp_path):
    scan1, scan2, c2c = ns["scan1"], ns["scan2"], ns["c2c"]
    sample = np.random.default_rng(0).choice(len(scan2), 200, replace=False)
    ref = naive_nearest(scan2[sample], scan1)
    ref_d = ref[0] if isinstance(ref, tuple) else ref
    np.testing.assert_allclose(c2c.distance[sample], ref_d, atol=1e-12)
    # What the text says: the spacing dominates; the zone and the rest differ by far
    # less than the 10 mm the lining moved.
    zone, quiet = ns["zone"], ns["quiet"]
    assert abs(np.median(c2c.distance[zone]) - np.median(c2c.distance[quiet])) < 0.005
    assert "in the zone" in out


def check_tut_m3c2(ns, out, tmp_path):
    r, in_zone, outside = ns["result"], ns["in_zone"], ns["outside"]
    # The applied convergence is 10 mm in the zone and 0 outside (analytic truth).
    assert abs(np.nanmedian(r.distance[in_zone]) - 0.01) < 0.001
    assert abs(np.nanmedian(r.distance[outside])) < 0.001
    assert r.significant[in_zone].mean() > 0.95 and r.significant[outside].mean() < 0.05
    assert "M3C2 median" in out


CHECKS = {
    ("guide/getting-started.md", "The Python API in ten lines"): check_python_api,
    ("guide/tunnels-and-meshes.md", "The ray-casting engine in ten lines"): check_raycasting,
    ("guide/tunnels-and-meshes.md", "Generated tunnels"): check_generated,
    ("guide/sensors-and-scanning.md", "Simulated scanners"): check_scanners,
    ("guide/survey-workflow.md", "Control points, Helmert adjustment, drift correction"):
        check_helmert,
    ("guide/drives-robots-ros.md", "Real SLAM in the loop"): check_slam,
    ("tutorials/generate-a-tunnel.md", "A straight bored tunnel"): check_tut_tunnel,
    ("tutorials/generate-a-tunnel.md", "Cast rays inside it"): check_tut_rays,
    ("tutorials/generate-a-tunnel.md", "A second epoch"): check_tut_epoch2,
    ("tutorials/generate-a-tunnel.md", "Read it back"): check_tut_read_back,
    ("tutorials/scan-a-station.md", "The world"): check_tut_world,
    ("tutorials/scan-a-station.md", "A terrestrial laser scanner on a tripod"):
        check_tut_station,
    ("tutorials/scan-a-station.md", "The points and their fields"): check_tut_fields,
    ("tutorials/scan-a-station.md", "The points and their fields (2)"): check_tut_laz,
    ("tutorials/scan-a-station.md", "A spinning lidar on a trolley"): check_tut_drive,
    ("tutorials/compare-epochs.md", "Two epochs, two scans"): check_tut_two_scans,
    ("tutorials/compare-epochs.md", "Cloud to mesh: the scanner's noise"): check_tut_c2m,
    ("tutorials/compare-epochs.md", "Cloud to cloud: the point spacing"): check_tut_c2c,
    ("tutorials/compare-epochs.md", "M3C2: the change"): check_tut_m3c2,
}


def test_every_example_has_a_check():
    found = {(page, heading) for page, blocks in EXAMPLES.items() for heading, _ in blocks}
    assert found == set(CHECKS), "docs Python examples and their checks differ"


@pytest.mark.slow
@pytest.mark.parametrize("page", sorted(EXAMPLES))
def test_page_examples(page, tmp_path, monkeypatch, capsys):
    """Run the page's blocks in order in one namespace; check each after it ran."""
    monkeypatch.chdir(tmp_path)
    ns: dict = {}
    for heading, code in EXAMPLES[page]:
        exec(compile(code, f"docs/{page}: {heading}", "exec"), ns)
        CHECKS[(page, heading)](ns, capsys.readouterr().out, tmp_path)


# --- command lines ----------------------------------------------------------------------

def _shell_commands() -> list[tuple[str, str]]:
    """(page, line) for every ``tunnelsim ...`` command of the docs' bash blocks,
    continuation lines joined and comments dropped (as tests/test_readme.py does)."""
    out = []
    for page in _pages():
        for _, block in _blocks(page, "bash"):
            for line in block.replace("\\\n", " ").splitlines():
                for part in re.split(r"&&|;", line.split(" #")[0]):
                    part = part.split(">")[0].strip()
                    if part.startswith("tunnelsim ") and not part[10:].startswith("-"):
                        out.append((_rel(page), part))
    return out


SHELL = _shell_commands()


def test_the_docs_have_command_lines():
    assert len(SHELL) > 20


@pytest.mark.parametrize("page,line", SHELL)
def test_docs_command_lines_parse(page, line):
    """Each command line names a command and options it has, with values of the right
    kinds (the parser refuses anything else)."""
    from survey.cli.main import build_parser

    parser, commands = build_parser()
    argv = shlex.split(line)[1:]
    assert commands[argv[0]].parse(argv[1:]) is not None


def test_docs_figures_exist():
    for page in _pages():
        for link in re.findall(r"!\[[^\]]*\]\(([^)]+)\)", page.read_text(encoding="utf-8")):
            p = page.parent / link
            assert p.is_file() and p.read_bytes()[:4] == b"\x89PNG", (page, link)


# --- the build --------------------------------------------------------------------------

def _need_sphinx():
    missing = [m for m in SPHINX_PACKAGES if importlib.util.find_spec(m) is None]
    if missing:
        pytest.skip(f"the docs build needs {', '.join(missing)}: "
                    "pip install -e '.[docs]' (CI installs them with the test extra)")


def _sphinx(src: Path, out: Path, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-b", "html", "-q",
         "-d", str(out / ".doctrees"), *extra, str(src), str(out / "html")],
        capture_output=True, text=True, cwd=ROOT)


@pytest.mark.slow
def test_docs_build_without_warnings(tmp_path):
    """The whole site, warnings as errors, from a copy of docs/ (the build writes the API
    pages into its source tree); every public name has its page."""
    _need_sphinx()
    src = tmp_path / "docs"
    shutil.copytree(DOCS, src, ignore=shutil.ignore_patterns("_build", "generated"))
    (tmp_path / "benchmarks").symlink_to(ROOT / "benchmarks")   # guide/results.md includes it
    r = _sphinx(src, tmp_path)
    assert r.returncode == 0, r.stderr[-5000:]
    html = tmp_path / "html"
    for page in _pages():
        assert (html / _rel(page)).with_suffix(".html").is_file(), page
    # Every name in the packages' __all__ has a page, wherever it is documented (the
    # reference is generated from __all__; a page per name, listed once).
    pages = {p.stem.rsplit("-", 1)[0] if p.stem.rsplit("-", 1)[-1] in
             ("class", "function", "exception", "data") else p.stem
             for p in (html / "api" / "generated").glob("*.html")}
    tails = {p.rsplit(".", 1)[-1] for p in pages}
    import raytrace
    import sensors
    import survey
    for pkg in (raytrace, sensors, survey):
        for name in pkg.__all__:
            obj = getattr(pkg, name)
            if name == "__version__" or type(obj).__name__ == "module":
                continue
            assert name in tails, f"{pkg.__name__}.{name} has no API page"
    assert "fit_helmert" in (html / "api" / "generated" / "survey.adjust.html").read_text()


def _tiny_site(src: Path, anchor: str) -> None:
    src.mkdir()
    (src / "index.md").write_text(
        "# Home\n\n```{toctree}\nother\n```\n\nSee [the part](other.md#" + anchor + ").\n")
    (src / "other.md").write_text("# Other\n\n## The part\n\nText.\n")


def test_broken_anchor_fails_the_build(tmp_path):
    """With the site's configuration, a link to a heading that does not exist is an
    error, and the same link to one that does builds: the guide's links are checked."""
    _need_sphinx()
    _tiny_site(tmp_path / "good", "the-part")
    ok = _sphinx(tmp_path / "good", tmp_path / "good_out", "-c", str(DOCS))
    assert ok.returncode == 0, ok.stderr
    _tiny_site(tmp_path / "bad", "no-such-part")
    bad = _sphinx(tmp_path / "bad", tmp_path / "bad_out", "-c", str(DOCS))
    assert bad.returncode != 0 and "no-such-part" in bad.stderr, bad.stderr
