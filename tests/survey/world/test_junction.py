"""Tunnels with a junction (survey.world.junction, the ``junction`` preset): closed
except at the portals, faces inward, galleries clear around their centrelines, the
recorded centrelines, files, seeds and bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

from raytrace import Scene
from survey.errors import TunnelError
from survey.world import preset
from survey.world.alignment import Alignment, curve, straight
from survey.world.deformation import Convergence
from survey.world.generator import ROUGHNESS_CLIP, make_tunnel
from survey.world.junction import Branch, branch_alignment, make_junction_tunnel
from survey.world.mesh import LABEL, read_tunnel
from survey.world.presets import BRANCHES, PRESETS
from survey.world.profiles import Profile, arched_rectangle, circle, horseshoe
from survey.world.rock import RockRelief
from tests.naive import naive_point_mesh

ROUGH = 0.003          # the preset's lining roughness (m)


@pytest.fixture(scope="module")
def coarse():
    return preset("junction", edge_length_m=0.25, seed=4)[0]


@pytest.fixture(scope="module")
def closed():
    return preset("junction", edge_length_m=0.2, seed=4, closed_ends=True)[0]


def _branch(tun):
    b = tun.metadata["branches"][0]
    return Alignment.from_dict(b["alignment"]), b


def _edges(faces):
    return np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])


def _open_only_at_portals(tun):
    """Every edge has two faces, used once each way (consistent winding), except the
    edges of the three portal rings; no duplicate or degenerate faces."""
    e = _edges(tun.faces)
    und, count = np.unique(np.sort(e, axis=1), axis=0, return_counts=True)
    assert set(np.unique(count)) <= {1, 2}
    assert len(np.unique(e, axis=0)) == len(e)
    assert len(np.unique(np.sort(tun.faces, axis=1), axis=0)) == len(tun.faces)
    border = np.unique(und[count == 1].ravel())
    s, _, _ = tun.alignment.to_local(tun.vertices[border])
    c0, c1 = tun.alignment.chainage_range
    bal, b = _branch(tun)
    sb, _, _ = bal.to_local(tun.vertices[border])
    at_portal = (np.abs(s - c0) < 1e-9) | (np.abs(s - c1) < 1e-9) | \
        (np.abs(sb - b["length_m"]) < 1e-9)
    assert at_portal.all()
    tri = tun.vertices[tun.faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]),
                                axis=1)
    longest = np.max(np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2), axis=1)
    assert (area / longest ** 2).min() > 1e-3
    return int(np.sum(count == 1))


def test_preset_is_open_exactly_at_its_three_portals(coarse):
    n_border = _open_only_at_portals(coarse)
    # Three portals, one border edge per ring vertex: as many as the ring has samples.
    k = int(np.sum(np.abs(coarse.vertex_chainage - coarse.alignment.chainage_range[0])
                   < 1e-12))
    assert n_border == 3 * k and k > 40
    assert trimesh.Trimesh(coarse.vertices, coarse.faces, process=False
                           ).is_winding_consistent


def test_closed_ends_enclose_the_union_of_the_two_galleries():
    """Volume of a capped T of straight galleries (no roughness) against the union's
    volume: main + branch - their overlap, where the overlap {0 <= y <= w(z),
    |x| <= w(z)} has volume int 2 w(z)^2 dz (w: the profile's half-width at height
    z). The sampled lining's own area comes from a plain capped tube of the same
    sampling (make_tunnel), so only the junction is under test."""
    prof = horseshoe(4.0, 1.5)
    al = Alignment([straight(30.0)])
    h = 0.05
    tun = make_junction_tunnel(al, prof, Branch(15.0, "right", 8.0), edge_length_m=h,
                               roughness_rms_m=0.0, closed_ends=True)
    mesh = trimesh.Trimesh(tun.vertices, tun.faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    plain = make_tunnel(al, prof, edge_length_m=h, roughness_rms_m=0.0, closed_ends=True)
    area = -trimesh.Trimesh(plain.vertices, plain.faces, process=False).volume / 30.0
    _, p = prof.dense()
    wall = p[(p[:, 0] > 0) & (p[:, 1] > 1e-9)]
    wall = wall[np.argsort(wall[:, 1])]
    z = np.linspace(0.0, wall[-1, 1], 20001)
    w = np.interp(z, np.concatenate([[0.0], wall[:, 1]]),
                  np.concatenate([[wall[0, 0]], wall[:, 0]]))
    overlap = np.trapezoid(2 * w ** 2, z)
    assert -mesh.volume == pytest.approx(area * 38.0 - overlap, abs=0.02)
    assert (tun.labels == LABEL["end_cap"]).sum() > 0


def test_rays_from_inside_all_hit_the_inner_side_of_a_closed_junction(closed):
    """pbrt's watertight test: rays from random points inside both galleries (the
    junction included) in random directions all hit, and each meets the front of an
    inward-facing face (so the centrelines are inside and the lining faces in)."""
    rng = np.random.default_rng(0)
    al, prof = closed.alignment, closed.profile
    bal, b = _branch(closed)
    cy, cz = prof.centroid
    n = 4000
    s = rng.uniform(*al.chainage_range, n)
    sj = b["chainage_m"]
    s[: n // 4] = rng.uniform(sj - 3.0, sj + 3.0, n // 4)         # around the junction
    pts = al.to_world(s, cy + rng.uniform(-1, 1, n), cz + rng.uniform(-1, 1, n))
    sb = rng.uniform(0.0, b["length_m"], n // 2)
    pts = np.concatenate([pts, bal.to_world(sb, cy + rng.uniform(-1, 1, n // 2),
                                            cz + rng.uniform(-1, 1, n // 2))])
    d = rng.normal(size=(len(pts), 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    hits = Scene(closed.vertices, closed.faces).cast(pts, d)
    assert np.isfinite(hits.t).all()
    assert (np.einsum("ij,ij->i", hits.normals, d) < 0).all()


def test_open_rays_escape_only_through_a_portal(coarse):
    """In the open preset a ray from the junction that misses must leave through one
    of the three portals: it crosses a portal's cross-section plane within the
    profile's extent there."""
    rng = np.random.default_rng(1)
    al, prof = coarse.alignment, coarse.profile
    bal, b = _branch(coarse)
    o = al.to_world(b["chainage_m"], prof.centroid[0], prof.centroid[1])[None]
    d = rng.normal(size=(20000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    hits = Scene(coarse.vertices, coarse.faces).cast(np.repeat(o, len(d), 0), d)
    miss = ~np.isfinite(hits.t)
    assert 0 < miss.sum() < 0.2 * len(d)
    left, right, zlo, zhi = prof.extent()
    through = np.zeros(len(d), bool)
    for a, sp in ((al, al.chainage_range[0]), (al, al.chainage_range[1]),
                  (bal, b["length_m"])):
        c = a.point(np.array([sp]))[0]
        tan, nrm, up = (v[0] for v in a.frame(np.array([sp])))
        with np.errstate(divide="ignore", invalid="ignore"):
            t = ((c - o[0]) @ tan) / (d @ tan)
        q = o[0] + t[:, None] * d - c
        through |= (t > 0) & (q @ nrm >= -right - 1e-6) & (q @ nrm <= left + 1e-6) & \
            (q @ up >= zlo - 1e-6) & (q @ up <= zhi + 1e-6)
    assert through[miss].all()


def test_centrelines_are_clear_of_the_walls(coarse):
    """The exact distance (every triangle tried) from points of both centrelines at the
    profile's centroid height to the mesh is at least the profile's own clearance
    there, less the roughness and the chords' sagitta; across the main gallery, away
    from the junction, the walls are the profile's half-width away on both sides."""
    al, prof = coarse.alignment, coarse.profile
    bal, b = _branch(coarse)
    cy, cz = prof.centroid
    design = float(prof.distance(prof.centroid[None])[0])
    tol = ROUGHNESS_CLIP * ROUGH + 0.25 ** 2 / (8 * 2.0) + 1e-6
    s = np.linspace(*al.chainage_range, 60)[1:-1]
    pts = np.concatenate([al.to_world(s, cy, cz),
                          bal.to_world(np.linspace(0.5, b["length_m"] - 0.5, 12), cy, cz)])
    dist, _ = naive_point_mesh(pts, coarse.vertices, coarse.faces)
    assert dist.min() >= design - tol
    # Horizontal rays across the main gallery (clear of the junction).
    sj = b["chainage_m"]
    s = s[np.abs(s - sj) > 3.0]
    _, nrm, _ = al.frame(s)
    o = al.to_world(s, cy, cz)
    half = np.abs(prof.points(prof.t_at_height("left", cz))[0])
    scene = Scene(coarse.vertices, coarse.faces)
    for sign in (1, -1):
        t = scene.cast(o, sign * nrm).t
        np.testing.assert_allclose(t, half, atol=tol)
    # At the junction the left wall is open: a ray to the left leaves by the branch
    # portal; from the branch, a ray back along its axis crosses the main gallery.
    oj = al.to_world(sj, cy, cz)
    assert not np.isfinite(scene.cast(oj, al.frame(sj)[1]).t[0])
    tb = scene.cast(bal.to_world(5.0, cy, cz), -bal.frame(5.0)[0]).t[0]
    assert tb == pytest.approx(5.0 + half, abs=tol)


def test_branch_centreline_is_recorded_and_files_round_trip(coarse, tmp_path):
    bal, b = _branch(coarse)
    assert b["side"] == BRANCHES["junction"].side
    assert b["chainage_m"] == BRANCHES["junction"].chainage_m
    ref = branch_alignment(coarse.alignment, BRANCHES["junction"])
    assert bal.to_dict() == ref.to_dict()
    line = np.array(b["centreline"])
    start = coarse.alignment.point(np.array([b["chainage_m"]]))[0]
    np.testing.assert_allclose(line[0], start, atol=1e-9)
    assert np.linalg.norm(line[-1] - line[0]) == pytest.approx(b["length_m"], abs=1e-9)
    # Perpendicular to the main gallery, on its left.
    tan, nrm, _ = coarse.alignment.frame(np.array([b["chainage_m"]]))
    direction = (line[-1] - line[0]) / b["length_m"]
    np.testing.assert_allclose(direction, nrm[0], atol=1e-12)
    ply, js = coarse.write(tmp_path / "j.ply")
    back = read_tunnel(ply)
    np.testing.assert_array_equal(back.vertices, coarse.vertices)
    np.testing.assert_array_equal(back.faces, coarse.faces)
    np.testing.assert_array_equal(back.labels, coarse.labels)
    np.testing.assert_array_equal(back.vertex_param, coarse.vertex_param)
    assert json.loads(js.read_text())["branches"] == json.loads(json.dumps(
        coarse.metadata["branches"]))
    assert back.alignment.to_dict() == coarse.alignment.to_dict()


def test_floor_labels_lie_on_the_floor(coarse):
    ctr = coarse.vertices[coarse.faces].mean(axis=1)
    s, _, h = coarse.alignment.to_local(ctr)
    floor = coarse.labels == LABEL["floor"]
    assert floor.sum() > 0.2 * len(floor)
    assert np.abs(h[floor]).max() <= ROUGHNESS_CLIP * ROUGH + 1e-9
    assert (h[~floor] > 0.01).all()


def test_preset_is_deterministic_by_seed():
    a = preset("junction", edge_length_m=0.3, seed=5)[0]
    b = preset("junction", edge_length_m=0.3, seed=5)[0]
    c = preset("junction", edge_length_m=0.3, seed=6)[0]
    smooth = preset("junction", edge_length_m=0.3, roughness_rms_m=0.0)[0]
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, c.faces)
    assert np.abs(a.vertices - c.vertices).max() > ROUGH
    # The roughness is the configured field: spatial rms = the rms, bounded by the clip.
    d = np.linalg.norm(a.vertices - smooth.vertices, axis=1)
    assert d.max() <= ROUGHNESS_CLIP * ROUGH + 1e-12
    assert np.sqrt(np.mean(d ** 2)) == pytest.approx(ROUGH, rel=0.1)


def test_second_epoch_moves_the_main_gallery_only(coarse):
    moved = coarse.deformed([Convergence(40.0, 50.0, 0.005)])
    assert np.isfinite(moved.vertices).all()
    br = ~np.isfinite(coarse.vertex_param)
    assert br.sum() > 0 and np.abs(moved.displacement[br]).max() == 0.0
    assert np.abs(moved.displacement).max() == pytest.approx(0.005, rel=1e-3)


def test_preset_parts_describe_the_main_gallery():
    al, prof, feats, deform = PRESETS["junction"]((100.0, 200.0, 10.0), 0.3)
    tun = preset("junction", edge_length_m=0.3, origin=(100.0, 200.0, 10.0),
                 heading_rad=0.3)[0]
    assert tun.alignment.to_dict() == al.to_dict()
    assert al.min_radius()[0] == pytest.approx(12.0)
    heading = al.heading(np.array(al.chainage_range))
    assert heading[1] - heading[0] == pytest.approx(np.pi / 2, abs=1e-12)
    assert feats == [] and deform == []


_PROFILES = {"horseshoe": horseshoe(4.0, 1.5), "arched": arched_rectangle(3.0, 1.5),
             "circle": circle(2.0)}


@settings(max_examples=12, deadline=None)
@given(name=st.sampled_from(sorted(_PROFILES)), side=st.sampled_from(["left", "right"]),
       chainage=st.floats(4.0, 22.0), length=st.floats(3.5, 12.0),
       edge=st.floats(0.25, 0.45))
def test_any_junction_is_closed_except_its_portals(name, side, chainage, length, edge):
    """Whatever profile, side, place, length and edge length: a manifold, consistently
    wound lining open only at the three portals, watertight once capped."""
    al = Alignment([straight(27.0), *curve(1.0, 15.0, 3.0)],
                   profile=((0.0, 5.0), (27.0, 5.0), (45.0, 6.0)))
    tun = make_junction_tunnel(al, _PROFILES[name], Branch(chainage, side, length),
                               edge_length_m=edge, seed=1)
    _open_only_at_portals(tun)
    capped = make_junction_tunnel(al, _PROFILES[name], Branch(chainage, side, length),
                                  edge_length_m=edge, closed_ends=True, seed=1)
    mesh = trimesh.Trimesh(capped.vertices, capped.faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume < 0


# ---------------------------------------------------------------------- bad input
def _al():
    return Alignment([straight(20.0), *curve(1.0, 15.0, 3.0)])


@pytest.mark.parametrize("make, match", [
    (lambda: Branch(5.0, "up", 5.0), "side 'left' or 'right'"),
    (lambda: Branch(5.0, "left", 0.0), "positive branch"),
    (lambda: Branch(np.nan, "left", 5.0), "finite branch"),
    (lambda: make_junction_tunnel(_al(), horseshoe(4.0), Branch(21.0, "left", 8.0)),
     "straight and level"),
    (lambda: make_junction_tunnel(_al(), horseshoe(4.0), Branch(1.0, "left", 8.0)),
     "branch chainage within"),
    (lambda: make_junction_tunnel(_al(), horseshoe(4.0), Branch(8.0, "left", 1.5)),
     "longer than the junction block"),
    (lambda: make_junction_tunnel(
        Alignment([straight(20.0)], profile=((0.0, 0.0), (20.0, 1.0))), horseshoe(4.0),
        Branch(8.0, "left", 5.0)), "straight and level"),
    (lambda: make_junction_tunnel(
        _al(), Profile.from_polyline([[-1, 0], [2, 0], [2, 2], [-1, 3]]),
        Branch(8.0, "left", 5.0)), "symmetric about its vertical axis"),
    (lambda: make_junction_tunnel(_al(), horseshoe(4.0), Branch(8.0, "left", 5.0),
                                  edge_length_m=0.0), "positive `edge_length_m`"),
    (lambda: make_junction_tunnel(Alignment([straight(20.0), *curve(1.0, 1.5, 0.5)]),
                                  horseshoe(4.0), Branch(8.0, "left", 5.0)),
     "fold on the inside"),
    (lambda: make_junction_tunnel(_al(), horseshoe(4.0), Branch(8.0, "left", 5.0),
                                  roughness_rms_m=-1.0), "roughness"),
    (lambda: preset("junction", relief=RockRelief()), "no rock relief"),
])
def test_bad_junction_input(make, match):
    with pytest.raises(TunnelError, match=match):
        make()


def test_drive_along_auto_keeps_to_the_centreline(coarse, tmp_path):
    """Issue 20: on the generated tunnel with a 90-degree bend and a junction,
    ``drive --along auto`` drives portal to portal along the main gallery; the route it
    writes lies within 10 cm (laterally) of the known centreline except within 2 m of
    the junction, covers >= 90 % of the gallery's length and keeps >= 0.2 m from the
    mesh (exact distance, every triangle tried)."""
    from survey.cli.main import main

    mesh = tmp_path / "j.ply"
    coarse.write(mesh)
    (tmp_path / "j.json").unlink()                 # any mesh: the route from the mesh alone
    out = tmp_path / "d.laz"
    assert main(["drive", "--mesh", str(mesh), "--sensor", "velodyne_vlp16", "--along",
                 "auto", "--speed", "1", "--duration", "0.3", "--rate", "5", "-o", str(out),
                 "--quiet"]) == 0
    rows = np.genfromtxt(tmp_path / "d_route.csv", delimiter=",", names=True)
    p = np.stack([rows["x"], rows["y"], rows["z"]], 1)
    al = coarse.alignment
    s, off, _ = al.to_local(p)
    sj = coarse.metadata["branches"][0]["chainage_m"]
    far = np.abs(s - sj) > 2.0
    assert np.abs(off[far]).max() <= 0.10
    c0, c1 = al.chainage_range
    assert (s.max() - s.min()) >= 0.9 * (c1 - c0)
    dist, _ = naive_point_mesh(p[::8], coarse.vertices, coarse.faces)
    assert dist.min() >= 0.2
