"""Tunnel generator: mesh topology, geometry against the design, labels, features,
files, resolution, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from survey.world import features as F
from survey.world.alignment import Alignment, curve, straight
from survey.errors import AlignmentError
from survey.errors import ProfileError
from survey.world.profiles import Profile, arched_rectangle, circle, horseshoe
from survey.world.mesh import LABEL, LABELS
from survey.world.generator import ROUGHNESS_CLIP, edge_length_for, make_tunnel
from survey.errors import TunnelError
from survey.world.mesh import read_tunnel
from tests.iofiles import mesh_fields as read_ply
from tests.naive import naive_cast

ROUGH = 0.002


def _alignment(origin=(0.0, 0.0), z0=0.0):
    return Alignment([straight(10.0), *curve(0.3, 60.0, 8.0), straight(10.0)],
                     start_xy=origin, heading_rad=0.4, profile=((0.0, z0), (50.0, z0 + 0.5)))


FEATURES = (F.Cable("left", 1.5, radius_m=0.02, start_m=2.0, end_m=40.0),
            F.Niche("right", 12.0, 13.5, 0.3, 1.9, depth_m=0.6),
            F.Drainage(-0.6, 0.3, 0.2),
            F.WetFloor(20.0, 30.0),
            F.Bolts((0.0, 0.6), spacing_m=3.0, start_m=5.0, end_m=40.0),
            F.Prisms((8.0, 25.0), (1.2, -1.2)))


@pytest.fixture(scope="module")
def tun():
    return make_tunnel(_alignment(), horseshoe(2.8), edge_length_m=0.1, features=FEATURES,
                       roughness_rms_m=ROUGH, seed=3)


def _edges(faces):
    return np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])


def test_manifold_consistent_and_open_exactly_at_the_portals(tun):
    e = _edges(tun.faces)
    und, count = np.unique(np.sort(e, axis=1), axis=0, return_counts=True)
    assert set(np.unique(count)) <= {1, 2}                      # manifold edges
    directed = np.unique(e, axis=0)
    assert len(directed) == len(e)                              # no edge used twice the same way
    c0, c1 = tun.alignment.chainage_range
    border = und[count == 1].ravel()
    s, _, _ = tun.alignment.to_local(tun.vertices[border])
    assert np.all((np.abs(s - c0) < 1e-9) | (np.abs(s - c1) < 1e-9))
    # Both portals are open along their whole ring: one border edge per ring vertex.
    # (The lining grid comes first, ring by ring: its first ring is the k vertices
    # before the first chainage above c0.)
    k = int(np.argmax(tun.vertex_chainage > c0))
    assert k > 50 and np.sum(count == 1) == 2 * k
    mesh = trimesh.Trimesh(tun.vertices, tun.faces, process=False)
    assert mesh.is_winding_consistent and not mesh.is_watertight


def test_closed_ends_are_watertight_and_enclose_the_profile_volume():
    """A plain tube with caps: watertight, and (Pappus) its volume is the profile area
    times the centreline length; the lining faces inward, so trimesh sees it inside
    out (negative volume)."""
    al = _alignment()
    prof = horseshoe(2.8)
    tun = make_tunnel(al, prof, edge_length_m=0.05, roughness_rms_m=0.0, closed_ends=True)
    mesh = trimesh.Trimesh(tun.vertices, tun.faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert -mesh.volume == pytest.approx(prof.area_m2 * al.length_m, rel=2e-4)
    assert (tun.labels == LABEL["end_cap"]).sum() > 0


def test_closed_ends_with_features_stay_watertight(tun):
    feats = [f for f in FEATURES if not isinstance(f, F.Drainage)]
    t2 = make_tunnel(_alignment(), horseshoe(2.8), edge_length_m=0.12, features=feats,
                     closed_ends=True)
    mesh = trimesh.Trimesh(t2.vertices, t2.faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent
    for body in mesh.split(only_watertight=False):     # every component is closed
        assert body.is_watertight


def test_no_degenerate_faces(tun):
    tri = tun.vertices[tun.faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    longest = np.max(np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2), axis=1)
    assert (area / longest ** 2).min() > 1e-3


def test_lining_vertices_lie_on_the_profile_up_to_the_roughness(tun):
    """to_local of each lining vertex gives back its ring chainage, and its distance
    from the design profile is the roughness: bounded by the clip, with the configured
    standard deviation."""
    lining = np.isin(tun.labels, [LABEL["lining"], LABEL["floor"], LABEL["wet_floor"]])
    only = np.zeros(len(tun.vertices), bool)
    only[tun.faces[lining].ravel()] = True
    only[tun.faces[~lining].ravel()] = False
    s, off, h = tun.alignment.to_local(tun.vertices[only])
    np.testing.assert_allclose(s, tun.vertex_chainage[only], atol=1e-9)
    d = tun.profile.distance(np.stack([off, h], 1))
    assert d.max() <= ROUGHNESS_CLIP * ROUGH + 1e-9
    assert np.sqrt(np.mean(d ** 2)) == pytest.approx(ROUGH, rel=0.15)
    smooth = make_tunnel(_alignment(), horseshoe(2.8), edge_length_m=0.2,
                         roughness_rms_m=0.0)
    s, off, h = smooth.alignment.to_local(smooth.vertices)
    assert smooth.profile.distance(np.stack([off, h], 1)).max() < 1e-9


def test_lining_faces_point_into_the_tunnel(tun):
    mesh = trimesh.Trimesh(tun.vertices, tun.faces, process=False)
    sel = np.isin(tun.labels, [LABEL["lining"], LABEL["floor"]])
    ctr = mesh.triangles_center[sel]
    s, _, _ = tun.alignment.to_local(ctr)
    axis = tun.alignment.to_world(s, tun.profile.centroid[0], tun.profile.centroid[1])
    assert np.all(np.einsum("ij,ij->i", mesh.face_normals[sel], axis - ctr) > 0)


def test_labels_cover_every_face_and_match_their_places(tun):
    assert tun.labels.dtype == np.uint8 and len(tun.labels) == len(tun.faces)
    assert tun.labels.max() < len(LABELS)
    for name in ("lining", "floor", "wet_floor", "drainage", "niche", "cable", "bolt",
                 "prism"):
        assert (tun.labels == LABEL[name]).any(), name
    assert sum(tun.metadata["face_counts"].values()) == len(tun.faces)
    ctr = tun.vertices[tun.faces].mean(axis=1)
    s, off, h = tun.alignment.to_local(ctr)
    wet = tun.labels == LABEL["wet_floor"]
    assert np.all((s[wet] > 20.0) & (s[wet] < 30.0)) and np.all(h[wet] < 0.01)
    floor = tun.labels == LABEL["floor"]
    assert np.all(h[floor] < 0.01)
    niche = tun.labels == LABEL["niche"]
    assert np.all((s[niche] > 12.0) & (s[niche] < 13.5) & (off[niche] < 0))
    refl = tun.reflectivity
    assert refl[wet].max() < refl[tun.labels == LABEL["lining"]].min()


def test_recesses_have_their_depth(tun):
    for label, depth in ((LABEL["niche"], 0.6), (LABEL["drainage"], 0.2)):
        v = np.unique(tun.faces[tun.labels == label].ravel())
        _, off, h = tun.alignment.to_local(tun.vertices[v])
        d = tun.profile.distance(np.stack([off, h], 1))
        assert d.max() == pytest.approx(depth, abs=ROUGHNESS_CLIP * ROUGH + 1e-6)


def _lining_hit(tun, s, t, lift):
    """Distance (n,) from the points lifted ``lift`` (n,) off the design lining at
    chainages s, profile parameters t (inward positive) to the lining mesh, along the
    outward design normal: all rays against the lining triangles near them."""
    prof, al = tun.profile, tun.alignment
    yz = prof.points(t) - prof.normals(t) * np.asarray(lift)[:, None]
    origin = al.to_world(s, yz[:, 0], yz[:, 1])
    tip = al.to_world(s, yz[:, 0] + prof.normals(t)[:, 0], yz[:, 1] + prof.normals(t)[:, 1])
    grid = np.isin(tun.labels, [LABEL["lining"], LABEL["floor"], LABEL["wet_floor"]])
    f = tun.faces[grid]
    fs, ft = tun.vertex_chainage[f].mean(axis=1), tun.vertex_param[f].mean(axis=1)
    out = np.empty(len(s))
    for i in range(len(s)):
        near = (np.abs(fs - s[i]) < 0.5) & (np.abs(ft - t[i]) < 0.5)
        hit, *_ = naive_cast(tun.vertices, f[near], origin[i:i + 1],
                             tip[i:i + 1] - origin[i:i + 1])
        out[i] = hit[0]
    return out


#: How far a point placed at the lining grid's relief, interpolated in (chainage, t),
#: can lie from the flat mesh triangles: the chord sagitta h^2 / (8 R) of a 0.1 m cell
#: on the 1.4 m crown radius (0.9 mm), plus the relief (<= 3.5 x 2 mm) times the turn of
#: the normal across the cell (0.1 / 1.4), plus rounding.
ON_MESH_M = 0.1 ** 2 / (8 * 1.4) + ROUGHNESS_CLIP * ROUGH * 0.1 / 1.4 + 1e-4


def test_cable_is_a_tube_of_its_radius_clear_of_the_wall(tun):
    """Each ring of the tube is a circle of the cable's radius whose centre lies on the
    design normal at the cable's height, gap + radius from the rough lining (ray cast
    against the lining triangles)."""
    v = np.unique(tun.faces[tun.labels == LABEL["cable"]].ravel())
    v = v[tun.vertex_param[v] == tun.vertex_param[v][0]]       # one cable's vertices
    s, off, h = tun.alignment.to_local(tun.vertices[v])
    prof = tun.profile
    t = prof.t_at_height("left", 1.5)
    p, n = prof.points(t), prof.normals(t)
    rings, inv = np.unique(np.round(s, 9), return_inverse=True)
    assert rings.min() == pytest.approx(2.0, abs=1e-9)
    assert rings.max() == pytest.approx(40.0, abs=1e-9)
    yz = np.stack([off, h], 1)
    ctr = np.array([yz[inv == i].mean(axis=0) for i in range(len(rings))])
    r = np.linalg.norm(yz - ctr[inv], axis=1)
    on_axis = r < 1e-9                                    # the two cap centres
    assert on_axis.sum() == 2
    np.testing.assert_allclose(r[~on_axis], 0.02, atol=1e-9)
    across = (ctr - p) @ np.array([-n[1], n[0]])          # off the normal line
    np.testing.assert_allclose(across, 0.0, atol=1e-9)
    lift = -(ctr - p) @ n                                 # into the tunnel
    assert np.abs(lift - 0.05).max() <= ROUGHNESS_CLIP * ROUGH + 1e-9
    pick = np.linspace(0, len(rings) - 1, 12).astype(int)
    clear = _lining_hit(tun, rings[pick], np.full(len(pick), t), lift[pick])
    np.testing.assert_allclose(clear, 0.05, atol=ON_MESH_M)


def test_prisms_are_control_points_at_their_standoff(tun):
    cps = tun.metadata["control_points"]
    assert len(cps) == 4 and len({c["id"] for c in cps}) == 4
    xyz = np.array([c["xyz"] for c in cps])
    s, off, h = tun.alignment.to_local(xyz)
    np.testing.assert_allclose(s, [8.0, 8.0, 25.0, 25.0], atol=1e-9)
    # The centre is the standoff from the rough lining along the design normal.
    t = np.array([c["profile_t_m"] for c in cps])
    lift = 0.1 - np.array([c["relief_m"] for c in cps])
    assert np.abs(lift - 0.1).max() <= ROUGHNESS_CLIP * ROUGH
    np.testing.assert_allclose(tun.profile.distance(np.stack([off, h], 1)), lift, atol=1e-9)
    np.testing.assert_allclose(_lining_hit(tun, s, t, lift), 0.1, atol=ON_MESH_M)
    sph = tun.labels == LABEL["prism"]
    v = tun.vertices[np.unique(tun.faces[sph].ravel())]
    near = np.linalg.norm(v[:, None, :] - xyz[None], axis=2).min(axis=1)
    assert np.isclose(near, 0.03, atol=1e-9).sum() >= 4 * 42   # icosphere vertices


def test_files_round_trip_through_an_independent_reader(tun, tmp_path):
    path = tmp_path / "t.ply"
    ply, js = tun.write(path)
    mesh = trimesh.load(str(ply), process=False)
    np.testing.assert_array_equal(mesh.vertices, tun.vertices)
    np.testing.assert_array_equal(mesh.faces, tun.faces)
    raw = mesh.metadata["_ply_raw"]["face"]["data"]
    np.testing.assert_array_equal(raw["label"], tun.labels)
    np.testing.assert_allclose(raw["reflectivity"], tun.reflectivity)
    meta = json.loads(js.read_text())
    assert meta["labels"] == {str(i): n for i, n in enumerate(LABELS)}
    back = read_tunnel(ply)
    np.testing.assert_array_equal(back.labels, tun.labels)
    np.testing.assert_array_equal(back.vertex_chainage, tun.vertex_chainage)
    assert back.alignment.to_dict() == tun.alignment.to_dict()
    assert back.profile.area_m2 == pytest.approx(tun.profile.area_m2, rel=1e-15)
    assert not list(tmp_path.glob("*.part"))
    assert read_ply(ply)["faces"].dtype == np.int64


def test_georeferenced_tunnel_keeps_its_precision():
    """The same tunnel at UTM coordinates equals the local one shifted, to 1e-6 m."""
    e, n, z = 451_234.567, 5_352_876.543, 612.3
    loc = make_tunnel(_alignment(), horseshoe(2.8), edge_length_m=0.25, seed=1)
    utm = make_tunnel(_alignment((e, n), z), horseshoe(2.8), edge_length_m=0.25, seed=1)
    np.testing.assert_allclose(utm.vertices - [e, n, z], loc.vertices, atol=1e-6, rtol=0)


@pytest.mark.parametrize("target", [50_000, 200_000])
def test_resolution_gives_the_requested_size(target):
    al, prof = _alignment(), arched_rectangle(3.0, 1.2)
    tun = make_tunnel(al, prof, edge_length_m=edge_length_for(target, prof, al.length_m))
    assert len(tun.faces) == pytest.approx(target, rel=0.1)


def test_roughness_field_does_not_depend_on_the_mesh():
    """A coarse and a fine mesh of the same seed carry the same surface: where their
    vertices coincide (every other ring and profile sample) they are identical. A
    different seed gives a different surface."""
    al = Alignment([straight(50.0)])
    prof = circle(2.0)
    h = prof.perimeter_m / 64                     # 64 and 128 samples around
    coarse = make_tunnel(al, prof, edge_length_m=h, seed=7)
    fine = make_tunnel(al, prof, edge_length_m=h / 2, seed=7)
    kc, kf = 64, 128
    vc = coarse.vertices.reshape(-1, kc, 3)
    vf = fine.vertices.reshape(-1, kf, 3)
    assert vf.shape[0] == 2 * vc.shape[0] - 1
    np.testing.assert_allclose(vf[::2, ::2], vc, atol=1e-12)
    other = make_tunnel(al, prof, edge_length_m=h, seed=8)
    assert np.abs(other.vertices - coarse.vertices).max() > ROUGH


# ---------------------------------------------------------------------- bad input
def test_self_intersecting_profile_is_rejected():
    with pytest.raises(ProfileError, match="non-self-intersecting"):
        Profile.from_polyline([[-1, 0], [1, 0], [-1, 2], [1, 2]])


def test_zero_length_is_rejected():
    with pytest.raises(AlignmentError, match="positive element length"):
        Alignment([straight(0.0)])


def test_radius_smaller_than_the_clothoids_allow_is_rejected():
    with pytest.raises(AlignmentError, match="smaller than the clothoids allow"):
        curve(0.1, 150.0, 20.0)          # clothoids alone turn 20/150 > 0.1 rad


def test_radius_tighter_than_the_tunnel_is_rejected():
    al = Alignment([straight(5.0), *curve(1.0, 1.2, 0.5)])
    with pytest.raises(TunnelError, match="fold on the inside"):
        make_tunnel(al, horseshoe(2.8), edge_length_m=0.2)


@pytest.mark.parametrize("kwargs, match", [
    ({"edge_length_m": 0.0}, "positive `edge_length_m`"),
    ({"edge_length_m": 1e-4}, "at most"),
    ({"roughness_rms_m": -1.0}, "roughness_rms_m"),
    ({"features": [F.Niche("left", 30.0, 60.0, 0.3, 1.5)]}, "within the tunnel"),
    ({"features": [F.Niche("left", 10.0, 12.0, 0.3, 1.5),
                   F.Niche("left", 11.0, 13.0, 1.0, 2.0)]}, "non-overlapping"),
    ({"features": [F.Niche("left", 10.0, 12.0, 0.3, 9.0)]}, "height within"),
    ({"features": ["cable"]}, "survey.world.features"),
    ({"features": [F.Drainage(0.0, 0.3, 0.2)], "closed_ends": True}, "closed ends"),
])
def test_bad_generator_input(kwargs, match):
    with pytest.raises((TunnelError, ProfileError), match=match):
        make_tunnel(_alignment(), horseshoe(2.8), **kwargs)


@pytest.mark.parametrize("make, match", [
    (lambda: F.Cable("up", 1.0), "side"),
    (lambda: F.Cable("left", 1.0, radius_m=0.0), "radius_m"),
    (lambda: F.Niche("left", 5.0, 4.0, 0.0, 1.0), "end_m > start_m"),
    (lambda: F.Prisms((1.0,), (0.0,), radius_m=0.05, standoff_m=0.04), "standoff_m"),
])
def test_bad_features(make, match):
    with pytest.raises(F.FeatureError, match=match):
        make()
