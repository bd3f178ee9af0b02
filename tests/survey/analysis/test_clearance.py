"""Clearance (issue 17, item 5): an envelope that the lining enters at known places (two
bulges on a generated tunnel, one deep enough), violations found exactly there with the
right depth; every violating cell against a brute-force point-in-polygon and distance
reference; regions across the invert seam; the artefacts of ``tunnelsim clearance``
and one clear error per bad input."""

from __future__ import annotations

import csv
import functools
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from survey.analysis.clearance import box_envelope, clearance, clearance_file, read_envelope
from survey.analysis.design import DesignProfile
from survey.analysis.developed import DevelopedFrame, mesh_samples
from survey.cli.main import main
from survey.errors import CompareError, ProfileError
from survey.world.alignment import Alignment, straight
from survey.world.deformation import Bulge
from survey.world.generator import make_tunnel
from survey.world.mesh import write_tunnel
from survey.world.profiles import circle

UTM = (512_345.678, 5_345_678.901)
R = 3.0
#: Free space between the lining and the envelope (a circle 3 cm inside the lining).
GAP = 0.03
DEEP = Bulge(chainage_m=6.0, angle_rad=0.5, radius_m=1.0, amplitude_m=0.05)
SHALLOW = Bulge(chainage_m=9.0, angle_rad=-1.2, radius_m=0.6, amplitude_m=0.02)


@functools.lru_cache(maxsize=None)
def _design() -> DesignProfile:
    return DesignProfile.from_profile(circle(R))


def _ring_envelope(radius: float) -> DesignProfile:
    a = np.linspace(0.0, 2 * np.pi, 1440, endpoint=False)
    return DesignProfile(np.stack([radius * np.cos(a), R + radius * np.sin(a)], 1),
                         closed=True, name=f"ring {radius:g} m")


@pytest.fixture(scope="module")
def bulged():
    al = Alignment([straight(12.0)], start_xy=UTM, heading_rad=-0.7, profile=((0.0, 55.0),))
    tun = make_tunnel(al, circle(R), edge_length_m=0.1, roughness_rms_m=0.0)
    return al, tun.deformed([DEEP, SHALLOW])


def test_envelope_entered_by_a_bulge_is_found_there_with_its_depth(bulged):
    al, tun = bulged
    env = _ring_envelope(R - GAP)
    res = clearance(mesh_samples(tun.vertices, tun.faces, 0.05), al, env, _design(),
                    cell_m=0.1)
    # One region: the deep bulge (5 cm into a 3 cm gap), not the shallow one (2 cm).
    assert len(res.regions) == 1
    reg = res.regions[0]
    assert reg.max_depth_m == pytest.approx(DEEP.amplitude_m - GAP, abs=5e-4)
    assert reg.deepest_chainage_m == pytest.approx(DEEP.chainage_m, abs=0.03)
    assert reg.deepest_arc_m == pytest.approx(R * DEEP.angle_rad, abs=0.03)
    # Its position in the section: the lining point at the bulge, moved inward.
    y, z = (R - DEEP.amplitude_m) * np.sin(0.5), R + (R - DEEP.amplitude_m) * np.cos(0.5)
    assert reg.deepest_offset_m == pytest.approx(y, abs=0.03)
    assert reg.deepest_height_m == pytest.approx(z, abs=0.03)
    # Extent: the bump exceeds the gap where (1 + cos(pi r / Rb)) / 2 > GAP / A, i.e.
    # r < Rb acos(2 GAP / A - 1) / pi; the region's cells cover that disc and no more
    # than one cell beyond it.
    rr = DEEP.radius_m * np.arccos(2 * GAP / DEEP.amplitude_m - 1) / np.pi
    c = res.margin.grid.cell_s_m
    assert DEEP.chainage_m - rr - c <= reg.chainage_from_m <= DEEP.chainage_m - rr + 1e-9
    assert DEEP.chainage_m + rr - 1e-9 <= reg.chainage_to_m <= DEEP.chainage_m + rr + c
    u0 = R * DEEP.angle_rad
    ca = res.margin.grid.cell_arc_m
    assert u0 - rr - ca <= reg.arc_from_m <= u0 - rr + 1e-9
    assert u0 + rr - 1e-9 <= reg.arc_to_m <= u0 + rr + ca
    # Every violating cell lies in the disc (to a cell diagonal) and no cell outside
    # the region has a negative margin.
    v = res.violations
    assert (np.hypot(v.chainage_m - DEEP.chainage_m, v.arc_m - u0) < rr + 0.15).all()
    assert (v.region == 1).all() and np.all(np.diff(v.depth_m) <= 0)
    assert res.min_margin_m == pytest.approx(-(DEEP.amplitude_m - GAP), abs=5e-4)
    # The shallow bulge comes within 1 cm of the envelope, as it should.
    S, U = np.meshgrid(res.margin.grid.chainage_centres(), res.margin.grid.arc_centres())
    near = np.hypot(S - SHALLOW.chainage_m, U - R * SHALLOW.angle_rad) < 0.08
    assert np.nanmin(res.margin.min[near]) == pytest.approx(GAP - SHALLOW.amplitude_m,
                                                            abs=5e-4)


def _brute_margin(env: DesignProfile, yz: np.ndarray) -> np.ndarray:
    """Signed distance to a polygon: matplotlib's point-in-polygon and every edge."""
    from matplotlib.path import Path as MplPath

    a = env.vertices
    b = np.roll(a, -1, axis=0)
    ab = b - a
    w = np.clip(np.einsum("nkj,kj->nk", yz[:, None] - a[None], ab) / (ab ** 2).sum(1), 0, 1)
    d = np.linalg.norm(yz[:, None] - (a[None] + w[..., None] * ab[None]), axis=2).min(1)
    inside = MplPath(a).contains_points(yz)
    return np.where(inside, -d, d)


@settings(max_examples=15, deadline=None)
@given(st.integers(0, 10_000), st.floats(2.0, 5.5), st.floats(3.0, 5.5),
       st.floats(0.0, 0.05))
def test_every_violating_cell_matches_brute_force(seed, width, height, required):
    al = Alignment([straight(3.0)], start_xy=UTM, heading_rad=1.1)
    rng = np.random.default_rng(seed)
    n = 3000
    t = rng.uniform(0, _design().length_m, n)
    yz = _design().points(t) + _design().normals(t) * rng.normal(0, 0.2, n)[:, None]
    s = rng.uniform(0.001, 2.999, n)
    p = al.to_world(s, yz[:, 0], yz[:, 1])
    env = box_envelope(width, height, bottom_m=0.3)
    res = clearance(np.array_split(p, 4), al, env, _design(), cell_m=0.25,
                    required_m=required)
    margin = _brute_margin(env, yz)
    bad = margin < required
    assert res.violating_points == int(bad.sum())
    fr = DevelopedFrame(al, _design())
    _, u, _, _, _ = fr.locate(p)
    cells = res.margin.grid.cells(s, u)
    want = {}
    for c, depth in zip(cells[bad], (required - margin)[bad]):
        want[c] = max(want.get(c, -np.inf), depth)
    got = dict(zip(res.margin.grid.cells(res.violations.chainage_m, res.violations.arc_m),
                   res.violations.depth_m))
    assert set(got) == set(want)
    for c in want:
        assert got[c] == pytest.approx(want[c], abs=1e-9)
    assert res.violations.points.sum() == bad.sum()
    # Regions are the 8-connected components of the violating cells (wrapping in arc).
    assert sum(r.cells for r in res.regions) == len(want)


def test_a_region_across_the_invert_seam_is_one_region():
    al = Alignment([straight(2.0)])
    ang = np.linspace(-np.pi, np.pi, 2000, endpoint=False)
    s = np.repeat(np.linspace(0.05, 1.95, 20), len(ang))
    a = np.tile(ang, 20)
    p = al.to_world(s, R * np.sin(a), R + R * np.cos(a))   # the lining, a = 0 the crown
    env = box_envelope(1.0, 0.1, bottom_m=-0.05)            # a slab across the invert
    res = clearance(p, al, env, _design(), cell_m=0.1)
    assert len(res.regions) == 1
    reg = res.regions[0]
    assert reg.arc_from_m > reg.arc_to_m          # it runs across u = +-pi R
    # The slab holds the lining where |y| <= 0.5 (there z = R - sqrt(R^2 - y^2) is
    # 0.042 m, below the slab's top at 0.05 m): half an arc of R asin(0.5 / R).
    half = R * np.arcsin(0.5 / R)
    assert np.pi * R - reg.arc_from_m == pytest.approx(half, abs=0.11)
    assert reg.max_depth_m == pytest.approx(0.05, abs=1e-4)   # the invert, 5 cm deep


def test_cli_clearance_artefacts(bulged, tmp_path):
    al, tun = bulged
    ply = tmp_path / "t2.ply"
    write_tunnel(tun, ply)
    env = tmp_path / "envelope.csv"
    a = np.linspace(0, 2 * np.pi, 720, endpoint=False)
    np.savetxt(env, np.stack([(R - GAP) * np.cos(a), R + (R - GAP) * np.sin(a)], 1),
               delimiter=",", header="y,z", comments="")
    out = tmp_path / "clr"
    assert main(["clearance", str(ply), "--envelope", str(env), "--cell", "0.2", "-o",
                 str(out), "--quiet"]) == 0
    names = {p.name for p in out.iterdir()}
    assert {"violations.csv", "regions.csv", "clearance.md", "clearance.json"} <= names
    stem = "clearance_margin_0+000.000_0+012.000"
    assert {f"{stem}.png", f"{stem}.npy", f"{stem}.json"} <= names
    assert (out / f"{stem}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    rows = list(csv.DictReader((out / "regions.csv").open()))
    assert len(rows) == 1 and float(rows[0]["max_depth_m"]) == pytest.approx(0.02, abs=1e-3)
    viol = list(csv.DictReader((out / "violations.csv").open()))
    assert viol and all(r["region"] == "1" for r in viol)
    assert float(viol[0]["chainage_m"]) == pytest.approx(6.0, abs=0.1)
    js = json.loads((out / "clearance.json").read_text())
    assert js["regions"][0]["region"] == 1 and js["max_depth_m"] == pytest.approx(0.02,
                                                                                 abs=1e-3)
    md = (out / "clearance.md").read_text()
    assert "1 violation region" in md and f"{stem}.png" in md
    side = json.loads((out / f"{stem}.json").read_text())
    m = np.load(out / f"{stem}.npy")
    assert side["statistic"] == "min" and side["field"] == "margin"
    assert np.nanmin(m) == pytest.approx(-0.02, abs=1e-3)


def test_file_and_array_give_the_same_result(tmp_path):
    al = Alignment([straight(3.0)], start_xy=UTM)
    tun = make_tunnel(al, circle(R), edge_length_m=0.25, roughness_rms_m=0.0)
    ply = tmp_path / "t.ply"
    write_tunnel(tun, ply)
    env = box_envelope(4.0, 5.0)
    a = clearance_file(ply, al, env, _design(), cell_m=0.5, mesh_spacing_m=0.1)
    b = clearance(mesh_samples(tun.vertices, tun.faces, 0.1), al, env, _design(),
                  cell_m=0.5)
    assert a.points == b.points and len(a.regions) == len(b.regions) >= 1
    assert np.allclose(a.violations.depth_m, b.violations.depth_m, atol=1e-9)


# ---------------------------------------------------------------------- bad input
def test_one_clear_error_per_bad_input(tmp_path):
    al = Alignment([straight(2.0)])
    p = np.array([[1.0, 0.0, 1.0]])
    arch = DesignProfile([[2, 0], [0, 2], [-2, 0]], closed=False)
    with pytest.raises(CompareError, match="closed envelope"):
        clearance(p, al, arch, _design())
    with pytest.raises(CompareError, match="`required_m` >= 0"):
        clearance(p, al, box_envelope(2, 2), _design(), required_m=-0.1)
    with pytest.raises(ProfileError, match="positive width and height"):
        box_envelope(0.0, 2.0)
    with pytest.raises(ProfileError, match="box:WIDTH,HEIGHT"):
        read_envelope("box:4")
    with pytest.raises(ProfileError, match="does not exist"):
        read_envelope(tmp_path / "missing.csv")
    bow = tmp_path / "bow.csv"
    bow.write_text("y,z\n0,0\n1,1\n1,0\n0,1\n")
    with pytest.raises(ProfileError, match="does not cross itself"):
        read_envelope(bow)


@pytest.mark.parametrize("envelope, message", [
    ("box:4", "box:WIDTH,HEIGHT"),
    ("nowhere.csv", "does not exist"),
])
def test_cli_errors_are_one_line_exit_2(tmp_path, capsys, envelope, message):
    al = Alignment([straight(2.0)])
    tun = make_tunnel(al, circle(R), edge_length_m=0.5, roughness_rms_m=0.0)
    ply = tmp_path / "t.ply"
    write_tunnel(tun, ply)
    out = tmp_path / "clr"
    assert main(["clearance", str(ply), "--envelope", envelope, "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
    assert not out.exists()
