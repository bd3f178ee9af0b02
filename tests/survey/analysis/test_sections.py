"""Sections against design (issue 17, item 1): cuts of meshes and clouds, deviations,
areas and volumes against analytic values and the generator's known overbreak field,
design profiles against brute force, invariance under UTM-sized rigid motions, the
artefacts of ``tunnelsim sections`` and one clear error per bad input."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from survey.analysis.design import DesignProfile, read_design_profile
from survey.analysis.overbreak import compare_sections
from survey.analysis.sections import SectionCut, cut_cloud, cut_mesh, section_chainages
from survey.cli.main import main
from survey.errors import AlignmentError, CompareError, ProfileError
from survey.world.alignment import Alignment, arc, straight
from survey.world.generator import make_tunnel
from survey.world.profiles import circle, horseshoe
from survey.world.rock import RockRelief, surface_relief

UTM = (512_345.678, 5_345_678.901)


def _brute(design: DesignProfile, p):
    """Unsigned distance of points to every segment of the design (reference)."""
    a = design.vertices
    b = np.roll(a, -1, axis=0) if design.closed else a[1:]
    a = a if design.closed else a[:-1]
    ab = b - a
    w = np.clip(np.einsum("nkj,kj->nk", p[:, None] - a[None], ab) / (ab ** 2).sum(1), 0, 1)
    foot = a[None] + w[..., None] * ab[None]
    return np.linalg.norm(p[:, None] - foot, axis=2).min(axis=1)


# ---------------------------------------------------------------------- design profiles
@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000), st.floats(0.3, 3.0), st.integers(3, 40))
def test_locate_matches_brute_force_and_point_in_polygon(seed, scale, k):
    from matplotlib.path import Path as MplPath

    rng = np.random.default_rng(seed)
    # Star-shaped about the origin, hence simple, only if no angular gap reaches pi (a
    # fan of angles within a half-plane can cross itself: seed 107, k 4 did): one
    # angle in each of k equal sectors, jittered over half of it, keeps every gap
    # below 1.5 x 2 pi / k <= pi.
    ang = (np.arange(k) + rng.uniform(0.0, 0.5, k)) * (2 * np.pi / k)
    rad = scale * rng.uniform(0.5, 1.5, k)
    v = np.stack([rad * np.cos(ang), rad * np.sin(ang)], 1)   # star-shaped: simple
    d = DesignProfile(v, closed=True)
    p = rng.uniform(-2 * scale, 2 * scale, (400, 2))
    dev, t = d.locate(p)
    assert np.allclose(np.abs(dev), _brute(d, p), atol=1e-12)
    inside = MplPath(d.vertices).contains_points(p)
    far = np.abs(dev) > 1e-9
    assert np.array_equal((dev < 0)[far], inside[far])
    foot = d.points(t)
    assert np.allclose(np.linalg.norm(p - foot, axis=1), np.abs(dev), atol=1e-9)
    assert ((t >= 0) & (t <= d.length_m)).all()


def test_locate_open_profile_marks_points_beyond_the_ends():
    # An arch without invert: the upper half of a circle of radius 2.
    ang = np.linspace(0, np.pi, 181)
    d = DesignProfile(np.stack([2 * np.cos(ang), 2 * np.sin(ang)], 1), closed=False)
    dev, _ = d.locate(np.array([[0.0, 2.1], [0.0, 1.9], [0.0, -1.0], [2.0, -0.5]]))
    assert dev[0] == pytest.approx(0.1, abs=1e-3) and dev[1] == pytest.approx(-0.1, abs=1e-3)
    assert np.isnan(dev[2:]).all()


def test_design_file_angle_order_shift_and_closure(tmp_path):
    # A digitised circle saved sorted by x (as the shared Chinese profile is).
    ang = np.linspace(0, 2 * np.pi, 200, endpoint=False)
    p = np.stack([3 + 2 * np.cos(ang), 5 + 2 * np.sin(ang)], 1)
    p = p[np.argsort(p[:, 0])]
    f = tmp_path / "design.csv"
    f.write_text("x,y\n" + "\n".join(f"{a:.4f},{b:.4f}" for a, b in p))
    # In file order the zigzag is a valid open polyline (it does not cross itself),
    # just not the profile: nothing can tell, so the order is the user's choice.
    zigzag = read_design_profile(f)
    assert not zigzag.closed and zigzag.length_m > 5 * 4 * np.pi
    d = read_design_profile(f, order="angle", shift_m=(-3, -3))
    assert d.closed
    assert d.area_m2 == pytest.approx(np.pi * 4, rel=1e-3)
    assert np.allclose(d.centre, [0, 2], atol=1e-3)
    arch = read_design_profile(f, order="angle", closed=False)
    assert not arch.closed


@pytest.mark.parametrize("pts, match", [
    ([[0, 0], [1, 1], [1, 0], [0, 1]], "cross itself"),           # a bow tie
    ([[0, 0], [1, 0]], "at least two segments"),
    ([[0, 0], [1, 0], [1, 0]], "at least two segments"),
    ([[0, 0], [np.nan, 1], [1, 0]], "finite"),
])
def test_bad_design_profiles(pts, match):
    with pytest.raises(ProfileError, match=match):
        DesignProfile(np.array(pts, float), closed=len(pts) == 4)


# ---------------------------------------------------------------------- mesh truth
@pytest.fixture(scope="module")
def relief_tunnel():
    """A drill-and-blast tunnel in UTM coordinates on a straight and a curve, with the
    rock relief's known overbreak. Edge 1 cm: where the floor taper bends the overbreak
    fastest (f'' ~ 13 /m) a mesh of edge h departs from the field by h^2 f'' / 8, 0.16 mm
    at 1 cm but 0.65 mm at 2 cm."""
    al = Alignment([straight(1.5), arc(2.5, 60.0)], start_xy=UTM, heading_rad=0.3,
                   profile=((0, 400.0), (4, 400.08)))
    rel = RockRelief()
    tun = make_tunnel(al, horseshoe(2.8, 1.4), edge_length_m=0.01, relief=rel, seed=3)
    return al, rel, tun


def _truth(tun, rel, s, t):
    c0, c1 = tun.alignment.chainage_range
    return surface_relief(tun.profile, [s], t, c0, c1, texture_rms_m=rel.texture_rms_m,
                          texture_corr_m=rel.texture_corr_m, relief=rel, seed=3)[0]


def test_mesh_sections_recover_the_known_overbreak(relief_tunnel):
    al, rel, tun = relief_tunnel
    rings = np.unique(tun.vertex_chainage)
    # Cut on grid rings: between rings the mesh interpolates the look-out's kinks.
    s = rings[np.searchsorted(rings, [0.5, 1.5, 2.5, 3.5])]
    design = DesignProfile.from_profile(tun.profile)
    # Cut samples every mm: a bin's median stands for its centre to within the sample
    # spacing times the slope of the deviation (up to ~0.9 in the floor taper).
    rep = compare_sections(cut_mesh(tun.vertices, tun.faces, al, s, spacing_m=0.001),
                           design, alignment=al, bin_m=0.02)
    for sec in rep.sections:
        truth = _truth(tun, rel, sec.chainage_m, sec.t_m)
        assert sec.coverage == 1.0
        assert np.abs(sec.deviation_m - truth).max() <= 1e-3
        assert sec.max_m == pytest.approx(truth.max(), abs=1e-3)
        assert sec.min_m == pytest.approx(truth.min(), abs=1e-3)
        assert sec.mean_m == pytest.approx(truth.mean(), abs=1e-3)
        assert sec.max_m > 0.1    # the test has teeth: decimetre overbreak
    # Area against the field integrated with the curvature term, on a fine grid.
    sec = rep.sections[1]
    tt = np.linspace(0, tun.profile.perimeter_m, 20_001)[:-1]
    f = _truth(tun, rel, sec.chainage_m, tt)
    p, n = tun.profile.points(tt), tun.profile.normals(tt)
    q = p + f[:, None] * n
    a_out = 0.5 * np.sum(q[:, 0] * np.roll(q[:, 1], -1) - np.roll(q[:, 0], -1) * q[:, 1])
    assert sec.net_area_m2 == pytest.approx(a_out - tun.profile.area_m2, rel=5e-3)


@pytest.mark.parametrize("curved", [False, True])
def test_volume_matches_the_analytic_annulus(curved):
    # A circle of radius 2.6 about the design circle of radius 2.5 (concentric):
    # overbreak area pi (2.6^2 - 2.5^2) everywhere, on a straight or a 30 m curve
    # (the annulus's centroid lies on the axis, so Pappus changes nothing).
    al = Alignment([arc(20.0, 30.0)] if curved else [straight(20.0)], start_xy=UTM)
    tun = make_tunnel(al, circle(2.6), edge_length_m=0.05, roughness_rms_m=0.0)
    design = DesignProfile.from_profile(circle(2.5)).shifted(0, 0.1)
    rep = compare_sections(cut_mesh(tun.vertices, tun.faces, al, np.arange(2.0, 19, 2.0)),
                           design, alignment=al)
    exact = np.pi * (2.6 ** 2 - 2.5 ** 2) * 16.0
    assert rep.overbreak_m3 == pytest.approx(exact, rel=5e-3)
    assert rep.underbreak_m3 == 0.0


def test_pappus_volume_on_a_curve_with_one_sided_overbreak():
    # Overbreak only on the left wall, on a left curve of radius 20 m: the swept volume
    # is A (1 - y / R) per metre (Pappus), not A.
    d = DesignProfile(np.array([[-1, 0], [1, 0], [1, 2], [-1, 2]], float), closed=True)
    yz = np.stack([np.full(400, -1.1), np.linspace(0.2, 1.8, 400)], 1)
    al = Alignment([arc(10.0, 20.0)])
    cuts = [SectionCut(s, 0.0, yz, len(yz)) for s in (2.0, 8.0)]
    rep = compare_sections(cuts, d, alignment=al, max_gap_m=0.0)
    a = rep.sections[0].overbreak_area_m2
    assert rep.sections[0].overbreak_offset_m == pytest.approx(-1.05, abs=0.01)
    assert rep.overbreak_m3 == pytest.approx(6.0 * a * (1 + 1.05 / 20.0), rel=1e-3)


def test_simulated_scan_recovers_the_overbreak_to_the_noise_level():
    # Points on the relieved lining (no look-out, whose kinks a band would average)
    # plus 3 mm of range noise along the normal: each bin median scatters by
    # 1.2533 sigma / sqrt(n) (the median's efficiency); 4 of those bound it.
    al = Alignment([straight(20.0)], start_xy=UTM, heading_rad=1.1,
                   profile=((0.0, 312.0),))
    prof = horseshoe(2.8, 1.4)
    rel = RockRelief(lookout_m=0.0)
    rng = np.random.default_rng(7)
    sigma, w = 0.003, 0.05
    chunks, s_k = [], [5.0, 10.0, 15.0]
    for sk in s_k:
        s = np.linspace(sk - w, sk + w, 11)
        t = rng.uniform(0, prof.perimeter_m, 4000)
        f = surface_relief(prof, s, t, 0.0, 20.0, texture_rms_m=0.01, texture_corr_m=0.3,
                           relief=rel, seed=5)
        ss = np.repeat(s, len(t))
        tt = np.tile(t, len(s))
        yz = prof.points(tt) + (f.ravel() + rng.normal(0, sigma, tt.size))[:, None] * \
            prof.normals(tt)
        chunks.append(al.to_world(ss, yz[:, 0], yz[:, 1]))
    pts = np.concatenate(chunks)
    cuts = cut_cloud(np.array_split(rng.permutation(pts), 7), al, s_k, w)
    rep = compare_sections(cuts, DesignProfile.from_profile(prof), alignment=al)
    for sec in rep.sections:
        truth = surface_relief(prof, [sec.chainage_m], sec.t_m, 0.0, 20.0,
                               texture_rms_m=0.01, texture_corr_m=0.3, relief=rel, seed=5)[0]
        tol = 1e-3 + 4 * 1.2533 * sigma / np.sqrt(sec.count.clip(1))
        assert (np.abs(sec.deviation_m - truth) <= tol).all()
        assert abs(sec.mean_m - truth.mean()) <= 1e-3


# ---------------------------------------------------------------------- streaming
def _ring_cloud(al, s_k, n, rng):
    s = rng.uniform(al.chainage_range[0], al.chainage_range[1], n)
    ang = rng.uniform(0, 2 * np.pi, n)
    r = 2.5 + 0.05 * np.sin(3 * ang) + rng.normal(0, 0.002, n)
    return al.to_world(s, r * np.cos(ang), 2.5 + r * np.sin(ang))


def test_cut_cloud_streams_with_a_bounded_subset_independent_of_chunking():
    al = Alignment([straight(10.0), arc(10.0, 25.0)])
    rng = np.random.default_rng(1)
    pts = _ring_cloud(al, None, 200_000, rng)
    s_k = [4.0, 12.0]
    a = cut_cloud(np.array_split(pts, 3), al, s_k, 0.1, max_points=500)
    b = cut_cloud(np.array_split(pts, 17), al, s_k, 0.1, max_points=500)
    s, _, _ = al.to_local(pts)
    for ca, cb, sk in zip(a, b, s_k):
        assert len(ca.yz) == 500 and ca.n_in_band == int((np.abs(s - sk) <= 0.1).sum())
        assert np.array_equal(ca.yz, cb.yz)
    full = cut_cloud(pts, al, s_k, 0.1)
    # Every point within a band is found (exact to_local as the reference).
    assert [len(c.yz) for c in full] == [int((np.abs(s - sk) <= 0.1).sum()) for sk in s_k]


@settings(max_examples=8, deadline=None)
@given(st.floats(-np.pi, np.pi), st.floats(-1e5, 1e5), st.floats(-1e5, 1e5),
       st.floats(-500, 500))
def test_sections_invariant_under_a_utm_sized_rigid_motion(heading, dx, dy, dz):
    rng = np.random.default_rng(3)
    base = Alignment([straight(8.0), arc(12.0, 40.0)], profile=((0.0, 0.0), (20, 0.4)))
    pts = _ring_cloud(base, None, 30_000, rng)
    moved = Alignment(base.elements, start_xy=(UTM[0] + dx, UTM[1] + dy),
                      heading_rad=heading, profile=((0.0, dz), (20, dz + 0.4)))
    s, off, h = base.to_local(pts)
    pts2 = moved.to_world(s, off, h)    # the same cloud, rigidly moved with its axis
    design = DesignProfile.from_profile(circle(2.5))
    r1 = compare_sections(cut_cloud(pts, base, [5.0, 15.0], 0.2), design, alignment=base)
    r2 = compare_sections(cut_cloud(pts2, moved, [5.0, 15.0], 0.2), design,
                          alignment=moved)
    for a, b in zip(r1.sections, r2.sections):
        assert a.n_points == b.n_points
        assert np.allclose(a.deviation_m, b.deviation_m, atol=1e-6, equal_nan=True)
        assert a.overbreak_area_m2 == pytest.approx(b.overbreak_area_m2, abs=1e-6)
    assert r1.overbreak_m3 == pytest.approx(r2.overbreak_m3, abs=1e-5)


# ---------------------------------------------------------------------- errors
def test_section_chainages_and_errors():
    al = Alignment([straight(20.0)], start_chainage_m=100.0)
    assert section_chainages(al, every_m=5, half_width_m=0.1).tolist() == \
        [105.0, 110.0, 115.0]
    with pytest.raises(AlignmentError, match="within the alignment"):
        section_chainages(al, at=[99.0], half_width_m=0.1)
    with pytest.raises(AlignmentError, match="within the alignment"):
        section_chainages(al, at=[119.95], half_width_m=0.1)
    with pytest.raises(CompareError, match="must not overlap"):
        section_chainages(al, at=[105.0, 105.1], half_width_m=0.1)
    with pytest.raises(CompareError, match="either `every_m` or `at`"):
        section_chainages(al, half_width_m=0.1)
    with pytest.raises(AlignmentError, match="within the alignment"):
        cut_cloud(np.zeros((5, 3)), al, [130.0], 0.1)


def test_empty_band_is_one_clear_error():
    al = Alignment([straight(20.0)])
    pts = _ring_cloud(Alignment([straight(8.0)]), None, 5000, np.random.default_rng(0))
    cuts = cut_cloud(pts, al, [4.0, 15.0], 0.1)
    assert len(cuts[1].yz) == 0
    with pytest.raises(CompareError, match=r"points in the section band at chainage 15 m"):
        compare_sections(cuts, DesignProfile.from_profile(circle(2.5)))


def test_points_all_beyond_an_open_design_is_an_error():
    arch = DesignProfile(np.array([[-1, 1], [0, 2], [1, 1]], float), closed=False)
    cut = SectionCut(1.0, 0.1, np.array([[0.0, -3.0], [0.1, -3.0]]), 2)
    with pytest.raises(CompareError, match="beyond the ends of the open design"):
        compare_sections([cut], arch)


# ---------------------------------------------------------------------- CLI artefacts
def test_cli_sections_writes_the_as_built_report(tbm_mesh, tmp_path, capsys):
    mesh = tbm_mesh(0.1)
    out = tmp_path / "sec"
    assert main(["sections", str(mesh), "--at", "30,50,70", "-o", str(out)]) == 0
    names = sorted(p.name for p in out.iterdir())
    assert names == ["contours.csv", "report.html", "report.json", "report.md",
                     "section_0+030.000.png",
                     "section_0+050.000.png", "section_0+070.000.png", "sections.csv",
                     "volumes.csv"]
    # the report states its input with its checksum (issue 31) and the HTML embeds the
    # section plots it links
    import hashlib

    md = (out / "report.md").read_text(encoding="utf-8")
    assert hashlib.sha256(mesh.read_bytes()).hexdigest() in md
    html = (out / "report.html").read_text(encoding="utf-8")
    assert html.count("data:image/png;base64,") == 3
    rows = list(csv.DictReader(open(out / "sections.csv")))
    assert [float(r["chainage_m"]) for r in rows] == [30.0, 50.0, 70.0]
    # A smooth segmental lining: within 1 cm of the design except the cable (inside).
    for r in rows:
        assert abs(float(r["mean_m"])) < 0.005 and float(r["max_m"]) < 0.01
        assert float(r["coverage"]) == 1.0
        assert sum(float(r[k]) for k in r if k.startswith("share_")) == pytest.approx(1.0, abs=1e-3)
    vol = list(csv.DictReader(open(out / "volumes.csv")))
    assert [(float(v["from_m"]), float(v["to_m"])) for v in vol] == [(30, 50), (50, 70)]
    md = (out / "report.md").read_text()
    assert "| 50.000 |" in md and "![section 50.000 m](section_0+050.000.png)" in md
    rep = json.loads((out / "report.json").read_text())
    assert len(rep["sections"]) == 3 and rep["design"].startswith("circle")
    png = (out / "section_0+050.000.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000


@pytest.mark.parametrize("argv, match", [
    (["--at", "500"], "within the alignment"),
    ([], "--every M or --at"),
    (["--every", "10", "--design", "missing.csv"], "does not exist"),
])
def test_cli_sections_errors_are_one_line_and_leave_nothing(tbm_mesh, tmp_path, capsys,
                                                            argv, match):
    out = tmp_path / "sec"
    code = main(["sections", str(tbm_mesh(0.1)), "-o", str(out), *argv])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and match in err
    assert not out.exists()
