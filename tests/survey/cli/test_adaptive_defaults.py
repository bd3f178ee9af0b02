"""Defaults that adapt to the data and say what they chose (issue 31, item 4).

Clouds are made here about a known straight alignment at UTM-sized coordinates
(``_world``: chainage, arc length along the design from the crown and a deviation from
the design line -> world points through ``DevelopedFrame`` and ``Alignment.to_world``),
so every expected number follows from how the cloud was built:

- develop: a profile cloud (stations every STATION m) with a 3 mm deformation and a few
  portal-terrain points metres off: the colour scale is the 98th percentile of the
  written raster's |value| (mm-scale), the cell is the station spacing, and
  ``--limit-mm`` changes the JSON and the PNG;
- clearance: three intrusions, fragmented by the profile spacing and by rough noise,
  give three regions (not one per touching group), far-apart ones stay apart, and a
  brute-force union-find over the violating cells is the reference of the merge;
- rings: ``--min-height`` on a fitted axis is measured from the floor, a horseshoe
  gets one warning line with its rms;
- sections: a lamp classified 65 no longer counts as underbreak with ``--classes``.
"""

from __future__ import annotations

import csv
import functools
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from survey.analysis.clearance import clearance
from survey.analysis.design import DesignProfile
from survey.analysis.developed import DevelopedFrame, station_spacing
from survey.cli.main import main
from sensors.io.cloudmap import write_points_las
from survey.world.alignment import Alignment, straight
from survey.world.generator import make_tunnel
from survey.world.mesh import write_tunnel
from survey.world.profiles import circle, horseshoe

UTM = (512_345.678, 5_345_678.901)
R = 3.0
LENGTH = 20.0
STATION = 0.25       # profile spacing (m)
ARC_STEP = 0.01      # point spacing along a profile (m)


@functools.lru_cache(maxsize=None)
def _alignment() -> Alignment:
    return Alignment([straight(LENGTH)], start_xy=UTM, heading_rad=0.4,
                     profile=((0.0, 250.0),))


@functools.lru_cache(maxsize=None)
def _design() -> DesignProfile:
    return DesignProfile.from_profile(circle(R))


@pytest.fixture(scope="module")
def tunnel_json(tmp_path_factory):
    """A tunnel JSON (alignment + circle(R) profile) from ``tunnelsim tunnel``'s writer."""
    tun = make_tunnel(_alignment(), circle(R), edge_length_m=0.5, roughness_rms_m=0.0)
    _, js = write_tunnel(tun, tmp_path_factory.mktemp("tunnel") / "t.ply")
    return js


def _world(s, u, d):
    """World points (n, 3) at chainage s, arc length u (from the crown, + left) and
    deviation d (> 0 outside) of the design line."""
    frame = DevelopedFrame(_alignment(), _design())
    t = frame.design_t(u)
    yz = _design().points(t) + np.asarray(d)[:, None] * _design().normals(t)
    return _alignment().to_world(s, yz[:, 0], yz[:, 1])


def _profiles(step=STATION):
    """(s, u) of a profile cloud: stations every ``step`` m, points every ARC_STEP."""
    L = _design().length_m
    s0 = np.arange(step / 2, LENGTH - 0.1, step)
    u0 = np.arange(-L / 2, L / 2, ARC_STEP)
    s, u = np.meshgrid(s0, u0, indexing="ij")
    return s.ravel(), u.ravel()


# ---------------------------------------------------------------------- develop
def _deformation(s, u):
    """A smooth 3 mm deformation (m)."""
    return 0.003 * np.sin(2 * np.pi * s / 8.0) * np.cos(u / 2.0)


@pytest.fixture(scope="module")
def develop_cloud(tmp_path_factory):
    rng = np.random.default_rng(3)
    s, u = _profiles()
    d = _deformation(s, u) + rng.normal(0.0, 0.0003, len(s))
    # Portal terrain: the last two stations over a tenth of the arc, 2-3 m outside.
    terrain = (s > LENGTH - 0.7) & (np.abs(u - 4.0) < 0.9)
    d[terrain] = rng.uniform(2.0, 3.0, terrain.sum())
    path = tmp_path_factory.mktemp("dev") / "profiles.laz"
    write_points_las(path, _world(s, u, d))
    return path


def test_station_spacing_of_profiles_and_of_a_dense_cloud():
    rng = np.random.default_rng(0)
    s, _ = _profiles(0.5)
    assert station_spacing(s + rng.normal(0, 0.001, len(s))) == pytest.approx(0.5, abs=0.01)
    # A missing profile does not change it.
    assert station_spacing(s[np.abs(s - 5.25) > 0.1]) == pytest.approx(0.5, abs=0.01)
    assert station_spacing(rng.uniform(0, 20, 200_000)) == 0.0


def test_develop_scale_is_mm_and_the_cell_is_the_station_spacing(develop_cloud,
                                                                  tunnel_json, tmp_path,
                                                                  capsys):
    out = tmp_path / "dev"
    assert main(["develop", str(develop_cloud), "--tunnel-json", str(tunnel_json), "-o",
                 str(out)]) == 0
    said = capsys.readouterr().out
    meta = json.loads(next(out.glob("*.json")).read_text())
    data = np.load(next(out.glob("*.npy")))
    v = np.abs(data[np.isfinite(data)])
    # The terrain is enough to set a metre-sized bar at the old 99.9th percentile ...
    assert np.percentile(v, 99.9) > 1.0
    # ... while the scale now is the 98th percentile of the raster written: mm-scale.
    scale = meta["colour_scale"]
    assert scale["limit"] == pytest.approx(np.percentile(v, 98), rel=1e-5)
    assert 0.001 < scale["limit"] < 0.0035
    assert "98th percentile" in scale["chosen"] and scale["unit"] == "m"
    assert scale["cells_beyond_share"] == pytest.approx((v > scale["limit"]).mean())
    # One column per station.
    assert meta["grid"]["cell_chainage_m"] == pytest.approx(STATION)
    assert meta["grid"]["cell_arc_m"] == pytest.approx(0.05, rel=0.01)
    assert "stations every 0.250 m" in meta["cell_chosen"]
    assert (np.isfinite(data).mean() > 0.95)
    assert f"colour scale +-{1000 * scale['limit']:.1f} mm" in said
    assert "stations every 0.250 m" in said
    assert "Colour scale: " in (out / "developed.md").read_text()


def test_develop_limit_option_changes_the_json_and_the_png(develop_cloud, tunnel_json,
                                                           tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    assert main(["develop", str(develop_cloud), "--tunnel-json", str(tunnel_json), "-o",
                 str(a), "--quiet"]) == 0
    assert main(["develop", str(develop_cloud), "--tunnel-json", str(tunnel_json), "-o",
                 str(b), "--quiet", "--limit-mm", "10"]) == 0
    ja = json.loads(next(a.glob("*.json")).read_text())
    jb = json.loads(next(b.glob("*.json")).read_text())
    assert jb["colour_scale"]["limit"] == pytest.approx(0.010)
    assert jb["colour_scale"]["chosen"].startswith("given")
    assert ja["colour_scale"]["limit"] != pytest.approx(0.010)
    assert next(a.glob("*.png")).read_bytes() != next(b.glob("*.png")).read_bytes()
    np.testing.assert_array_equal(np.load(next(a.glob("*.npy"))),
                                  np.load(next(b.glob("*.npy"))))


def test_develop_tolerance_classes_colour_the_view(develop_cloud, tunnel_json, tmp_path,
                                                   capsys):
    a, b = tmp_path / "a", tmp_path / "b"
    base = ["develop", str(develop_cloud), "--tunnel-json", str(tunnel_json)]
    assert main([*base, "-o", str(a), "--quiet"]) == 0
    assert main([*base, "-o", str(b), "--tolerance", "-2,0,2"]) == 0
    said = capsys.readouterr().out
    jb = json.loads(next(b.glob("*.json")).read_text())
    scale = jb["colour_scale"]
    assert scale["class_edges"] == pytest.approx([-0.002, 0.0, 0.002])
    assert scale["chosen"].startswith("tolerance classes")
    data = np.load(next(b.glob("*.npy")))
    w = data[np.isfinite(data)]
    assert scale["cells_beyond_share"] == pytest.approx(((w < -0.002) | (w > 0.002)).mean())
    assert "colour classes at -2, 0, 2 mm (--tolerance)" in said
    assert next(a.glob("*.png")).read_bytes() != next(b.glob("*.png")).read_bytes()


@pytest.mark.parametrize("extra", [["--tolerance", "5,1"], ["--tolerance", "1,2",
                                                            "--limit-mm", "3"]])
def test_develop_bad_tolerance_is_one_line(develop_cloud, tunnel_json, tmp_path, capsys,
                                           extra):
    assert main(["develop", str(develop_cloud), "--tunnel-json", str(tunnel_json), "-o",
                 str(tmp_path / "x"), *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--tolerance" in err[0]


def test_develop_cell_option_overrides_the_choice(develop_cloud, tunnel_json, tmp_path,
                                                  capsys):
    out = tmp_path / "dev"
    assert main(["develop", str(develop_cloud), "--tunnel-json", str(tunnel_json), "-o",
                 str(out), "--cell", "0.1"]) == 0
    meta = json.loads(next(out.glob("*.json")).read_text())
    assert meta["grid"]["cell_chainage_m"] == pytest.approx(0.1)
    assert meta["cell_chosen"] == "cell 0.1 m along the chainage (--cell)"
    assert "(--cell)" in capsys.readouterr().out


def test_develop_bad_limit_is_one_line(develop_cloud, tunnel_json, tmp_path, capsys):
    assert main(["develop", str(develop_cloud), "--tunnel-json", str(tunnel_json), "-o",
                 str(tmp_path / "x"), "--limit-mm", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--limit-mm" in err[0]


# ---------------------------------------------------------------------- clearance
#: Intrusions (chainage from, to; arc from, to), m: the envelope is a circle GAP inside
#: the lining; each intrusion reaches 1-4 cm into it, fragmented by rough noise.
INTRUSIONS = [(3.0, 4.5, 1.0, 1.8), (9.0, 10.0, -3.0, -2.2), (15.0, 16.5, 6.0, 7.0)]
GAP = 0.03


def _ring_envelope(radius: float) -> DesignProfile:
    a = np.linspace(0.0, 2 * np.pi, 1440, endpoint=False)
    return DesignProfile(np.stack([radius * np.cos(a), R + radius * np.sin(a)], 1),
                         closed=True, name=f"ring {radius:g} m")


@pytest.fixture(scope="module")
def intruded(tmp_path_factory):
    rng = np.random.default_rng(7)
    s, u = _profiles()
    d = rng.normal(0.0, 0.003, len(s))            # rough lining, never 3 cm deep
    for a, b, lo, hi in INTRUSIONS:
        m = (s >= a) & (s <= b) & (u >= lo) & (u <= hi)
        # Rough: half the points of the intrusion stay on the lining.
        d[m] = np.where(rng.random(m.sum()) < 0.5, -rng.uniform(GAP + 0.01, GAP + 0.04,
                                                                 m.sum()), d[m])
    folder = tmp_path_factory.mktemp("clr")
    path = folder / "lining.laz"
    # Each profile slightly skew to the axis (+-1.5 cm), as a real profile scanner's: a
    # station then fills one or two 5 cm columns.
    write_points_las(path, _world(s + 0.015 * np.sin(u / R), u, d))
    env = folder / "ring.csv"
    np.savetxt(env, _ring_envelope(R - GAP).vertices, delimiter=",", header="y,z",
               comments="")
    return path, env


def _inside(region, box):
    a, b, lo, hi = box
    return a - 0.3 <= region["deepest_chainage_m"] <= b + 0.3 and \
        lo - 0.1 <= region["deepest_arc_m"] <= hi + 0.1


@pytest.mark.parametrize("cell", [None, "0.05"])
def test_clearance_gives_one_region_per_intrusion(intruded, tunnel_json, tmp_path, capsys,
                                                  cell):
    path, env = intruded
    out = tmp_path / "clr"
    extra = [] if cell is None else ["--cell", cell]
    assert main(["clearance", str(path), "--tunnel-json", str(tunnel_json), "--envelope",
                 str(env), "-o", str(out), *extra]) == 0
    said = capsys.readouterr().out
    res = json.loads((out / "clearance.json").read_text())
    assert len(res["regions"]) == len(INTRUSIONS)
    for box in INTRUSIONS:     # each intrusion holds exactly one region's deepest point
        assert sum(_inside(r, box) for r in res["regions"]) == 1
    for r in res["regions"]:
        assert GAP + 0.005 < r["max_depth_m"] < GAP + 0.041
    m = res["merge"]
    assert m["gap_m"] == pytest.approx(2 * STATION) and m["chosen"].startswith("auto")
    assert m["regions"] == 3 and m["touching_groups"] >= 3
    if cell == "0.05":   # 5 cm cells on 25 cm stations: every station its own group
        assert m["touching_groups"] > 3 * 5
    assert f"merged into 3 regions" in said
    assert "Regions: " in (out / "clearance.md").read_text()
    rows = list(csv.DictReader(open(out / "regions.csv")))
    assert len(rows) == 3


def test_clearance_merge_gap_zero_keeps_the_touching_groups(intruded, tunnel_json,
                                                            tmp_path):
    path, env = intruded
    out = tmp_path / "clr"
    assert main(["clearance", str(path), "--tunnel-json", str(tunnel_json), "--envelope",
                 str(env), "-o", str(out), "--cell", "0.05", "--merge-gap", "0",
                 "--quiet"]) == 0
    res = json.loads((out / "clearance.json").read_text())
    assert len(res["regions"]) == res["merge"]["touching_groups"] > 15
    assert res["merge"]["gap_m"] == 0


def test_clearance_bad_merge_gap_is_one_line(intruded, tunnel_json, tmp_path, capsys):
    path, env = intruded
    assert main(["clearance", str(path), "--tunnel-json", str(tunnel_json), "--envelope",
                 str(env), "-o", str(tmp_path / "x"), "--merge-gap", "wide"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--merge-gap" in err[0]


def _brute_force_components(cells, n_rows, gr, gc, wrap):
    """Union-find over violating cells: two join when at most gr empty rows (cyclic
    when wrap) and gc empty columns lie between them."""
    parent = list(range(len(cells)))

    def find(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for i, (ri, ci) in enumerate(cells):
        for j, (rj, cj) in enumerate(cells[:i]):
            dr = abs(ri - rj)
            if wrap:
                dr = min(dr, n_rows - dr)
            if dr <= gr + 1 and abs(ci - cj) <= gc + 1:
                parent[find(i)] = find(j)
    groups = {}
    for i in range(len(cells)):
        groups.setdefault(find(i), set()).add(cells[i])
    return sorted(sorted(g) for g in groups.values())


@settings(max_examples=25, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 24), st.integers(0, 39)), min_size=1, max_size=25,
                unique=True),
       st.sampled_from([0.0, 0.1, 0.25, 0.5]))
def test_merge_matches_a_brute_force_union_find(cells, gap):
    """Points at cell centres, all inside the envelope: the regions of ``clearance`` are
    the brute-force components of the merge rule (rows wrap on the closed design)."""
    cell = 0.1
    env = _ring_envelope(R + 1.0)       # the whole lining lies inside: all violate
    design = _design()
    frame = DevelopedFrame(_alignment(), design)
    from survey.analysis.developed import DevelopedGrid

    grid = DevelopedGrid.covering(frame, cell, chainage_range=(0.0, 4.0))
    rc = np.array(cells)
    # Rows 0-24 of the grid and the top rows (near the seam) for wrapping cases.
    rows = np.where(rc[:, 0] < 12, rc[:, 0], grid.n_arc - 25 + rc[:, 0])
    s = grid.chainage0_m + (rc[:, 1] + 0.5) * grid.cell_s_m
    u = grid.arc0_m + (rows + 0.5) * grid.cell_arc_m
    res = clearance(_world(s, u, np.zeros(len(s))), _alignment(), env, design,
                    cell_m=cell, chainage_range=(0.0, 4.0), merge_gap_m=gap)
    gr = int(np.floor(gap / grid.cell_arc_m + 1e-9))
    gc = int(np.floor(gap / cell + 1e-9))
    want = _brute_force_components([(int(r), int(c)) for r, c in zip(rows, rc[:, 1])],
                                   grid.n_arc, gr, gc, True)
    v = res.violations
    vr = np.floor((v.arc_m - grid.arc0_m) / grid.cell_arc_m).astype(int) % grid.n_arc
    vc = np.floor((v.chainage_m - grid.chainage0_m) / cell).astype(int)
    got = {}
    for k, r, c in zip(v.region, vr, vc):
        got.setdefault(int(k), set()).add((int(r), int(c)))
    assert sorted(sorted(g) for g in got.values()) == want
    assert res.meta["merge"]["regions"] == len(want)


# ---------------------------------------------------------------------- rings
FLOOR_BELOW_CENTRE = 2.0
RING_LENGTH = 60.0      # long enough for the axis fit to see a tunnel
RING_POINTS = 200_000


@pytest.fixture(scope="module")
def floored_ring(tmp_path_factory):
    """A circle R (centre 2 m above a flat floor) along a straight, level axis; the
    floor spans the chord; no lining below it. Returns the path and the true (y, z)
    about the circle centre of each point."""
    rng = np.random.default_rng(11)
    n = RING_POINTS
    al = Alignment([straight(RING_LENGTH)], start_xy=UTM, heading_rad=0.4,
                   profile=((0.0, 250.0),))
    half = np.sqrt(R ** 2 - FLOOR_BELOW_CENTRE ** 2)
    a0 = np.arcsin(-FLOOR_BELOW_CENTRE / R)             # the floor meets the circle
    arc = (np.pi - 2 * a0) * R
    share = arc / (arc + 2 * half)
    on_arc = rng.random(n) < share
    ang = rng.uniform(a0, np.pi - a0, n)
    y = np.where(on_arc, R * np.cos(ang), rng.uniform(-half, half, n))
    z = np.where(on_arc, R * np.sin(ang), -FLOOR_BELOW_CENTRE)
    y += rng.normal(0, 0.001, n)
    z += rng.normal(0, 0.001, n)
    s = rng.uniform(0.0, RING_LENGTH, n)
    path = tmp_path_factory.mktemp("ring") / "ring.laz"
    write_points_las(path, al.to_world(s, y, z + 4.0))
    return path


def test_rings_min_height_is_measured_from_the_floor_on_a_fitted_axis(floored_ring,
                                                                       tmp_path, capsys):
    out = tmp_path / "rings"
    at = [10, 20, 30, 40, 50]
    assert main(["rings", str(floored_ring), "--fit-axis", "--at", ",".join(map(str, at)),
                 "--min-height", "0.5", "-o", str(out)]) == 0
    said = capsys.readouterr()
    rows = json.loads((out / "rings.json").read_text())
    for r in rows:
        # The floor found lies 2 m below the fitted circle's centre (the geometry).
        assert r["circle_centre_z_m"] - r["floor_height_m"] == pytest.approx(
            FLOOR_BELOW_CENTRE, abs=0.005)
        assert r["circle_diameter_m"] == pytest.approx(2 * R, abs=0.003)
    # Kept: the arc from 0.5 m above the floor up, i.e. above z = -1.5 about the centre:
    # its share of the points (uniform over arc + floor) is 0.69 (measured from the
    # fitted axis, which runs 0.5 m above the centre, it would be 0.40).
    a_keep = np.arcsin(-(FLOOR_BELOW_CENTRE - 0.5) / R)
    a0 = np.arcsin(-FLOOR_BELOW_CENTRE / R)
    arc = (np.pi - 2 * a0) * R
    floor = 2 * np.sqrt(R ** 2 - FLOOR_BELOW_CENTRE ** 2)
    want = (np.pi - 2 * a_keep) * R / (arc + floor)
    in_bands = len(at) * RING_POINTS * 0.1 / RING_LENGTH   # ~1670, Poisson sd 2.4 %
    assert sum(r["n_points"] for r in rows) / in_bands == pytest.approx(want, rel=0.08)
    assert "above the floor: each section's lowest points" in said.out
    assert "warning" not in said.err


@pytest.mark.slow
def test_rings_rail_height_sets_the_floor(floored_ring, tmp_path):
    out = tmp_path / "rings"
    assert main(["rings", str(floored_ring), "--fit-axis", "--at", "30", "--min-height",
                 "0.5", "--rail-height", "-1.0", "-o", str(out), "--quiet"]) == 0
    row = json.loads((out / "rings.json").read_text())[0]
    assert row["floor_height_m"] == -1.0
    auto = tmp_path / "auto"
    assert main(["rings", str(floored_ring), "--fit-axis", "--at", "30", "--min-height",
                 "0.5", "-o", str(auto), "--quiet"]) == 0
    assert json.loads((auto / "rings.json").read_text())[0]["n_points"] > row["n_points"]


def test_rings_rail_height_alone_is_one_line(floored_ring, tmp_path, capsys):
    assert main(["rings", str(floored_ring), "--fit-axis", "--at", "30", "--rail-height",
                 "-1", "-o", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--min-height" in err[0]


def test_rings_warn_once_on_a_horseshoe(tmp_path, capsys):
    hs = DesignProfile.from_profile(horseshoe(6.0))
    t = np.arange(0.0, hs.length_m, 0.01)
    rng = np.random.default_rng(5)
    pts = []
    for s0 in (5.0, 10.0):
        yz = hs.points(t)
        s = s0 + rng.uniform(-0.02, 0.02, len(t))
        pts.append(_alignment().to_world(s, yz[:, 0], yz[:, 1]))
    cloud = tmp_path / "hs.laz"
    write_points_las(cloud, np.concatenate(pts))
    tun = make_tunnel(_alignment(), horseshoe(6.0), edge_length_m=0.5, roughness_rms_m=0.0)
    _, js = write_tunnel(tun, tmp_path / "hs.ply")
    out = tmp_path / "rings"
    assert main(["rings", str(cloud), "--tunnel-json", str(js), "--at", "5,10", "-o",
                 str(out)]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    rows = json.loads((out / "rings.json").read_text())
    worst = max(min(r["circle_rms_m"], r["ellipse_rms_m"]) for r in rows)
    assert worst > 0.025
    assert len(err) == 1 and err[0].startswith("tunnelsim: warning: 2 of 2 rings")
    assert f"worst {1000 * worst:.0f} mm" in err[0] and "--design" in err[0]


def test_rings_on_a_circle_do_not_warn(tmp_path, capsys, tunnel_json):
    rng = np.random.default_rng(6)
    s, u = _profiles(0.5)
    cloud = tmp_path / "c.laz"
    write_points_las(cloud, _world(s, u, rng.normal(0, 0.002, len(s))))
    assert main(["rings", str(cloud), "--tunnel-json", str(tunnel_json), "--at", "5.25",
                 "-o", str(tmp_path / "r"), "--width", "0.01"]) == 0
    assert "warning" not in capsys.readouterr().err


# ---------------------------------------------------------------------- sections
@pytest.fixture(scope="module")
def lamp_cloud(tmp_path_factory):
    """A lining (class 64) and, at the crown of chainage 10, a lamp 0.3 m inside it
    (class 65, as 'tunnelsim preprocess --segment' calls attachments)."""
    rng = np.random.default_rng(9)
    s, u = _profiles(0.05)
    keep = np.abs(s - 10.0) < 1.0
    s, u = s[keep], u[keep]
    lining = _world(s, u, rng.normal(0, 0.001, len(s)))
    n = 400
    ls, lu = rng.uniform(9.8, 10.2, n), rng.uniform(-0.2, 0.2, n)
    lamp = _world(ls, lu, np.full(n, -0.3))
    folder = tmp_path_factory.mktemp("lamp")
    path = folder / "lamp.laz"
    write_points_las(path, np.concatenate([lining, lamp]),
                     classification=np.concatenate([np.full(len(s), 64, np.uint8),
                                                    np.full(n, 65, np.uint8)]))
    ply = folder / "lamp.npz"
    xyz = np.concatenate([lining, lamp])
    np.savez(ply, x=xyz[:, 0], y=xyz[:, 1], z=xyz[:, 2])
    return path, ply


def _section_row(out):
    return list(csv.DictReader(open(out / "sections.csv")))[0]


def test_sections_classes_leave_the_lamp_out_of_the_underbreak(lamp_cloud, tunnel_json,
                                                              tmp_path):
    path, _ = lamp_cloud
    a, b = tmp_path / "all", tmp_path / "lining"
    base = ["sections", str(path), "--tunnel-json", str(tunnel_json), "--at", "10",
            "--no-plots", "--quiet"]
    assert main([*base, "-o", str(a)]) == 0
    assert main([*base, "-o", str(b), "--classes", "64,2"]) == 0
    ra, rb = _section_row(a), _section_row(b)
    # With the lamp: 0.3 m of underbreak; without it only the 1 mm noise of the lining.
    assert float(ra["min_m"]) == pytest.approx(-0.3, abs=0.01)
    assert float(ra["underbreak_area_m2"]) > 0.02
    assert float(rb["min_m"]) > -0.006
    assert float(rb["underbreak_area_m2"]) < 0.1 * float(ra["underbreak_area_m2"])
    assert int(rb["n_points"]) < int(ra["n_points"])


def test_sections_classes_need_a_classification(lamp_cloud, tunnel_json, tmp_path, capsys):
    _, npz = lamp_cloud
    assert main(["sections", str(npz), "--tunnel-json", str(tunnel_json), "--at", "10",
                 "-o", str(tmp_path / "x"), "--classes", "64"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--classes" in err[0] and "preprocess --segment" in err[0]


def test_sections_classes_refuse_a_mesh(tunnel_json, tmp_path, capsys):
    ply = tunnel_json.with_suffix(".ply")
    out = tmp_path / "x"
    assert main(["sections", str(ply), "--at", "10", "-o", str(out), "--classes", "64"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--classes" in err[0] and "mesh" in err[0]
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.parametrize("value", ["64.5", "300", "x"])
def test_sections_bad_classes_are_one_line(lamp_cloud, tunnel_json, tmp_path, capsys,
                                           value):
    path, _ = lamp_cloud
    assert main(["sections", str(path), "--tunnel-json", str(tunnel_json), "--at", "10",
                 "-o", str(tmp_path / "x"), "--classes", value]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--classes" in err[0]


def test_clearance_figure_labels_only_the_deepest_regions(intruded, tunnel_json, tmp_path,
                                                          monkeypatch):
    """Without merging (many regions), the figure labels the LABELLED_REGIONS deepest:
    the labels drawn are R1..R12 with the depths of regions.csv."""
    import survey.report.plotting as plotting
    from survey.report.developed import LABELLED_REGIONS

    figs = []
    real = plotting.save_png

    def keep(fig, path, **kw):
        figs.append([t.get_text() for ax in fig.axes for t in ax.texts] +
                    [ax.get_title() for ax in fig.axes])
        return real(fig, path, **kw)

    monkeypatch.setattr(plotting, "save_png", keep)
    path, env = intruded
    out = tmp_path / "clr"
    assert main(["clearance", str(path), "--tunnel-json", str(tunnel_json), "--envelope",
                 str(env), "-o", str(out), "--cell", "0.05", "--merge-gap", "0",
                 "--quiet"]) == 0
    rows = list(csv.DictReader(open(out / "regions.csv")))
    assert len(rows) > LABELLED_REGIONS
    labels = [t for t in figs[0] if t.startswith("R")]
    want = [f"R{r['region']}: {1000 * float(r['max_depth_m']):.0f} mm" for r in rows
            if int(r["region"]) <= LABELLED_REGIONS]
    assert sorted(labels) == sorted(want)
    assert any(f"the {LABELLED_REGIONS} deepest of {len(rows)} regions" in t
               for t in figs[0])


# ---------------------------------------------------------------------- mesh
def _profile_cloud(spacing_m: float, rng) -> np.ndarray:
    """Rings of a 3 m circle every ``spacing_m`` along a straight 60 m axis at UTM
    coordinates, a point every ~1 cm on each ring, 2 mm noise: a profile scanner's
    cloud."""
    al = Alignment([straight(60.0)], start_xy=UTM, heading_rad=0.4, profile=((0.0, 250.0),))
    s = np.arange(0.3, 60.0 - 0.3, spacing_m)
    a = np.arange(0.0, 2 * np.pi, ARC_STEP / R)
    ss, aa = np.meshgrid(s, a, indexing="ij")
    r = R + rng.normal(0.0, 0.002, ss.shape)
    off, up = r * np.sin(aa), 1.5 + r * np.cos(aa)
    return al.to_world(ss.ravel(), off.ravel(), up.ravel())


@pytest.mark.slow
def test_mesh_cell_is_the_profile_spacing_and_interpolates_less(tmp_path, capsys):
    # A profile cloud (0.5 m apart): without --cell the mesher takes one cell per
    # profile, says so, and records it; its interpolated share is far below that of
    # the old fixed 0.1 m cell on the same file (which leaves 4 of 5 columns empty).
    pts = _profile_cloud(0.5, np.random.default_rng(2))
    src = tmp_path / "profiles.laz"
    write_points_las(src, pts)
    runs = {}
    for name, extra in (("auto", []), ("fixed", ["--cell", "0.1,2"])):
        js = tmp_path / f"{name}.json"
        assert main(["mesh", str(src), "-o", str(tmp_path / f"{name}.ply"), "--json",
                     str(js), "--method", "tunnel", *extra]) == 0
        runs[name] = json.loads(js.read_text()), capsys.readouterr().out
    auto, out = runs["auto"]
    assert (auto["cell_chosen"]["cell_m"], auto["cell_chosen"]["cell_deg"]) == (0.5, 2.0)
    assert "profile" in auto["cell_chosen"]["how"]
    assert "cell: 0.5 m along the axis" in out and "--cell" in out
    fixed, out_fixed = runs["fixed"]
    assert "cell_chosen" not in fixed and "cell:" not in out_fixed
    assert fixed["extrapolated_share"] > 0.6
    assert auto["extrapolated_share"] < 0.1
    assert (tmp_path / "auto.ply").read_bytes() != (tmp_path / "fixed.ply").read_bytes()


@pytest.mark.slow
def test_mesh_cell_stays_fixed_on_a_dense_cloud(tmp_path, capsys):
    # Profiles 1 cm apart (a dense MLS cloud) are no profile cloud: the old default.
    pts = _profile_cloud(0.01, np.random.default_rng(3))[::40]
    src = tmp_path / "dense.laz"
    write_points_las(src, pts)
    js = tmp_path / "d.json"
    assert main(["mesh", str(src), "-o", str(tmp_path / "d.ply"), "--json", str(js),
                 "--method", "tunnel", "--quiet"]) == 0
    chosen = json.loads(js.read_text())["cell_chosen"]
    assert (chosen["cell_m"], chosen["cell_deg"]) == (0.1, 2.0)
    assert chosen["how"].startswith("default")
