"""A tunnel that runs out of a portal into the open (issue 18): the mesher and the
segmenter find where the lining ends from the data and keep the terrain beyond it (the
ground in front of the portal, the portal face around the opening, vegetation) out of
the lining.

The cloud is generated here by sampling surfaces directly (no mesh, no scanner: the
test needs points with known truth, and sampling keeps it fast):

- the lining: a horseshoe of 5 m span on a gently curved alignment, uniform in area
  over chainage [c0, portal] (denser in the last metres), 3 mm Gaussian noise along
  the surface normal;
- the ground in front of the portal: from the portal outwards along the end tangent,
  40 m wide, at the tunnel floor's level at the portal, rising across and falling away
  from it with a rough (decimetre) undulation;
- the portal face: a vertical wall at the portal chainage, 40 m wide and 12 m high,
  with the tunnel's opening cut out (the face the tunnel enters);
- vegetation: small random clusters (bushes) above the ground.

# DECISION: a test helper, not ``survey.world``: these are sampled points with labels,
# not a mesh the scanner simulator could use; a user-facing portal would be a terrain
# mesh joined to the lining mesh (future work).
"""

from __future__ import annotations

import numpy as np
import pytest

from survey.analysis.compare import cloud_to_mesh
from survey.clouds.axis import lining_extent, unroll
from survey.clouds.axis import extend_chainage
from survey.clouds.reconstruct import reconstruct_tunnel
from survey.clouds.segment import FLOOR, LINING, TERRAIN, segment_tunnel
from survey.world.alignment import Alignment, curve, straight
from survey.world.profiles import horseshoe

SPAN_M = 5.0
CENTRE_H = 2.5            # the horseshoe's springline, the profile centre above the floor
NOISE_M = 0.003           # lining noise (1 sigma), along the surface normal
LINING_PER_M2 = 400.0     # lining points per m^2, and DENSE_PER_M2 in the last DENSE_M
DENSE_PER_M2 = 2500.0     # before the portal (a 2 cm voxelised MLS cloud: ~2500
DENSE_M = 6.0             # everywhere; sparser elsewhere to keep the test fast)
TERRAIN_PER_M2 = 150.0    # farther from the scanner: sparser
# Truth labels of the generated points.
T_LINING, T_GROUND, T_FACE, T_VEG = 0, 1, 2, 3


def portal_cloud(seed: int = 0):
    """(alignment, profile, portal chainage, points (n, 3), labels (n,) int) of a
    tunnel whose lining ends at the portal (the alignment's end) with terrain beyond."""
    rng = np.random.default_rng(seed)
    al = Alignment([straight(30.0), *curve(0.15, 120.0, 5.0), straight(10.0)],
                   start_xy=(1000.0, 2000.0))
    prof = horseshoe(SPAN_M)
    c0, portal = al.chainage_range
    # Lining: uniform in (chainage, arc length) = uniform in area (the alignment's
    # curvature changes the area by < 2 % at 120 m radius).
    n = int(LINING_PER_M2 * (portal - c0) * prof.perimeter_m)
    n_near = int((DENSE_PER_M2 - LINING_PER_M2) * DENSE_M * prof.perimeter_m)
    s = np.concatenate([rng.uniform(c0, portal, n), rng.uniform(portal - DENSE_M, portal,
                                                                n_near)])
    n = len(s)
    t = rng.uniform(0.0, prof.perimeter_m, n)
    yz = prof.points(t) + rng.normal(0.0, NOISE_M, n)[:, None] * prof.normals(t)
    lining = al.to_world(s, yz[:, 0], yz[:, 1])
    # The portal's frame: origin on the centreline at the portal, u along the end
    # tangent (out of the tunnel), v to the left, z up.
    (tan,), (nrm,), _ = al.frame(np.array([portal]))
    origin = al.point(portal)

    def world(u, v, z):
        return origin + u[:, None] * tan + v[:, None] * nrm + z[:, None] * np.array(
            [0.0, 0.0, 1.0])

    def ground_z(u, v):
        return (0.05 * np.abs(v) - 0.04 * u + 0.1 * np.sin(0.7 * u) * np.cos(0.5 * v)
                + rng.normal(0.0, 0.02, len(u)))

    n = int(TERRAIN_PER_M2 * 20.0 * 40.0)
    u, v = rng.uniform(0.0, 20.0, n), rng.uniform(-20.0, 20.0, n)
    ground = world(u, v, ground_z(u, v))
    # Face: the wall at u = 0 (rough, 5 cm), without the opening.
    n = int(TERRAIN_PER_M2 * 40.0 * 12.0)
    v, z = rng.uniform(-20.0, 20.0, n), rng.uniform(0.0, 12.0, n)
    inside = _inside_profile(prof, v, z)
    v, z = v[~inside], z[~inside]
    face = world(rng.normal(0.0, 0.05, len(v)), v, z)
    # Vegetation: 40 bushes of 150 points, 0.3-0.5 m across, up to 2 m above ground.
    cu, cv = rng.uniform(1.0, 20.0, 40), rng.uniform(-18.0, 18.0, 40)
    ch = ground_z(cu, cv) + rng.uniform(0.4, 2.0, 40)
    k = np.repeat(np.arange(40), 150)
    sz = rng.uniform(0.3, 0.5, 40)[k]
    veg = world(cu[k] + rng.normal(0, 1, len(k)) * sz, cv[k] + rng.normal(0, 1, len(k)) * sz,
                ch[k] + rng.normal(0, 1, len(k)) * sz)
    pts = np.concatenate([lining, ground, face, veg])
    lab = np.repeat([T_LINING, T_GROUND, T_FACE, T_VEG],
                    [len(lining), len(ground), len(face), len(veg)])
    order = rng.permutation(len(pts))
    return al, prof, portal, pts[order], lab[order]


def _inside_profile(prof, v, z):
    """Points (v, z) of a cross-section inside the closed profile (even-odd rule on the
    profile sampled every 2 cm)."""
    poly = prof.points(prof.sample(0.02))
    inside = np.zeros(len(v), dtype=bool)
    for (ya, za), (yb, zb) in zip(poly, np.roll(poly, -1, axis=0)):
        cross = (za > z) != (zb > z)
        with np.errstate(divide="ignore", invalid="ignore"):
            y_at = ya + (z - za) * (yb - ya) / (zb - za)
        inside ^= cross & (v < y_at)
    return inside


def _true_chainage(al, pts):
    s, off, h = al.to_local(pts)
    return extend_chainage(al, pts, s), off, h


@pytest.fixture(scope="module")
def portal():
    """portal_cloud() and the true chainage (n,) of every point."""
    al, prof, s_p, pts, lab = portal_cloud()
    return al, prof, s_p, pts, lab, _true_chainage(al, pts)[0]


@pytest.mark.parametrize("known_axis", [True, False])
def test_mesh_ends_at_the_portal_and_stays_on_the_lining(portal, known_axis):
    al, prof, s_p, pts, lab, sl = portal
    cell_m = 0.1
    rec = reconstruct_tunnel(pts, alignment=al if known_axis else None,
                             centre_height_m=CENTRE_H if known_axis else None,
                             cell_m=cell_m, cell_rad=np.deg2rad(2.0))
    s, off, h = _true_chainage(al, rec.vertices)
    # The mesh ends within one ring spacing of the true portal.
    assert abs(s.max() - s_p) <= cell_m, s.max() - s_p
    # No vertex on the terrain (which lies >= 0.25 m off the lining: the portal face
    # around the opening, the ground beyond; before issue 18 a vertex of the last rings
    # lay 13 m off). In the dense last DENSE_M every vertex within 25 mm of the true
    # lining: noise 3 mm on the median of ~20-40 points a cell, plus the 2 deg cells
    # across the floor's corners, where the radius changes by |dr/dphi| ~ 2.3 m/rad
    # (39 mm a half-cell) and the median lands off the centre angle's radius by up to
    # ~17 mm (measured, with both axes; elsewhere on the ring ~3 mm). In the sparse
    # rest (3-4 points a cell; a quarter of the cells have fewer than 3 and are
    # interpolated) the supported vertices within 35 mm (31 mm measured) and the
    # interpolated ones within 0.15 m (0.11 m measured).
    d = prof.distance(np.stack([off, h], 1))
    dense = s > s_p - DENSE_M + cell_m
    assert d[dense].max() <= 0.025, (d[dense].max(), s[dense][np.argmax(d[dense])])
    assert d[rec.support > 0].max() <= 0.035 and d.max() <= 0.15, (d.max(),
                                                                   s[np.argmax(d)])
    # C2M of the true lining points to the mesh in the last metre before the portal (up
    # to the last ring: the half ring beyond it is open, as at any end) at the noise
    # level: a point with 3 mm Gaussian noise lies sigma sqrt(2/pi) = 2.4 mm from the
    # true surface on average, and the mesh (cell medians) is within ~1 mm of it. The
    # test asserts a mean |C2M| <= 3.5 mm there, and no worse than 1.2 x the mean at
    # 1-5 m from the portal (the same density, away from the face and the ground).
    rng = np.random.default_rng(1)
    c2m = []
    for lo, hi in ((s_p - 1.0, s.max()), (s_p - 5.0, s_p - 1.0)):
        idx = np.flatnonzero((lab == T_LINING) & (sl > lo) & (sl < hi))
        q = pts[rng.choice(idx, 5000, replace=False)]
        c2m.append(np.abs(cloud_to_mesh(q, rec.vertices, rec.faces).distance).mean())
    assert c2m[0] <= 0.0035 and c2m[0] <= 1.2 * c2m[1], c2m


def test_lining_extent_finds_the_portal(portal):
    al, prof, s_p, pts, lab, sl = portal
    _, hc, s, _, _, phi, rho = unroll(pts, al, CENTRE_H)
    s = extend_chainage(al, pts, s)
    ext = lining_extent(s, phi, rho, ring_m=0.25)
    assert abs(ext.end_m - s_p) <= 0.25
    assert abs(ext.start_m - al.chainage_range[0]) <= 0.25     # the cut end of the lining
    assert ext.portal_end and not ext.portal_start              # terrain at one end only
    terrain = ext.terrain(s, phi, rho)
    assert np.mean(terrain[lab == T_LINING]) < 0.005
    assert np.mean(terrain[lab != T_LINING]) > 0.99


def test_segmenter_classes_the_terrain(portal):
    al, prof, s_p, pts, lab, sl = portal
    for known in (True, False):
        cls = segment_tunnel(pts, alignment=al if known else None,
                             centre_height_m=CENTRE_H if known else None)
        lin = lab == T_LINING
        assert np.mean(np.isin(cls[lin], [LINING, FLOOR])) >= 0.97, known
        for t in (T_GROUND, T_FACE, T_VEG):
            assert np.mean(cls[lab == t] == TERRAIN) >= 0.97, (known, t)
