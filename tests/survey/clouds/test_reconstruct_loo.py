"""Leave one out on a generated curved tunnel with realistic ring-to-ring variation (a
drill-and-blast rock relief), as benchmarks/validate_real_tunnel.py does on Ringo: the
mesh from the even profiles, with an axis estimated from them, predicts each odd profile
at least as well as a real neighbour profile moved into its plane (the floor), on a
curve and up to the portals (issue 18)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from raytrace import Scene
from survey.clouds.axis import estimate_axis
from survey.clouds.axis import extend_chainage
from survey.clouds.reconstruct import reconstruct_tunnel
from survey.world.alignment import Alignment, curve, straight
from survey.world.generator import make_tunnel
from survey.world.profiles import horseshoe
from survey.world.rock import RockRelief

SPACING_M = 0.5          # profile spacing, as Ringo's
RAYS = 1440              # rays per profile (0.25 deg)
CENTRE_H = 2.0           # profiler height above the centreline (m)


def _profile(scene, al, s):
    """The points of a profile scanned at chainage s in the plane normal to the true
    axis, from CENTRE_H above the centreline (rays every 0.25 deg)."""
    t, n, up = (x[0] for x in al.frame(np.array([s])))
    a = np.linspace(0, 2 * np.pi, RAYS, endpoint=False)
    d = np.cos(a)[:, None] * up + np.sin(a)[:, None] * n
    o = al.to_world(s, 0.0, CENTRE_H)
    hit = scene.cast(np.broadcast_to(o, d.shape), d)
    ok = np.isfinite(hit.t)
    return o + hit.t[ok, None] * d[ok], o, t


@pytest.fixture(scope="module")
def curved():
    al = Alignment([straight(8.0), *curve(0.5, 60.0, 4.0), straight(8.0)])
    tun = make_tunnel(al, horseshoe(5.0), edge_length_m=0.05, relief=RockRelief(), seed=3)
    return al, Scene(tun.vertices, tun.faces)


def test_leave_one_out_beats_the_neighbour_floor_on_a_curve(curved):
    al, scene = curved
    c0, c1 = al.chainage_range
    ss = np.arange(c0 + 0.25, c1 - 0.2, SPACING_M)
    profiles = [_profile(scene, al, s) for s in ss]
    even = [p for i, p in enumerate(profiles) if i % 2 == 0]
    train = np.concatenate([p[0] for p in even])
    est, hc = estimate_axis(train)
    # Each ring at its profile's chainage on the estimated axis (which may run either
    # way), extended straight beyond its ends (the end profiles lie past them: the
    # estimate's first and last slice centres are ~2 m inside the data).
    rows = np.sort([np.median(extend_chainage(est, p[0], est.to_local(p[0])[0]))
                    for p in even])
    rec = reconstruct_tunnel(train, alignment=est, centre_height_m=hc, rows_at=rows,
                             min_points=1, cell_rad=np.radians(0.5))
    mesh = Scene(rec.vertices, rec.faces)
    means, floors = [], []
    for i in range(1, len(profiles) - 1, 2):
        real, o, t = profiles[i]
        tree = cKDTree(real)
        # The prediction: the same profiler, same plane, on the mesh.
        a = np.linspace(0, 2 * np.pi, RAYS, endpoint=False)
        _, n, up = (x[0] for x in al.frame(np.array([ss[i]])))
        d = np.cos(a)[:, None] * up + np.sin(a)[:, None] * n
        hit = mesh.cast(np.broadcast_to(o, d.shape), d)
        ok = np.isfinite(hit.t)
        assert ok.mean() > 0.99                     # the mesh is closed around the ring
        means.append(tree.query(o + hit.t[ok, None] * d[ok])[0].mean())
        # The floor: each real neighbour carried rigidly into this profile's frame.
        fl = []
        for j in (i - 1, i + 1):
            q, oj, tj = profiles[j]
            yaw = np.arctan2(t[1], t[0]) - np.arctan2(tj[1], tj[0])
            moved = Rotation.from_euler("z", yaw).apply(q - oj) + o
            fl.append(tree.query(moved)[0].mean())
        floors.append(np.mean(fl))
    means, floors = np.array(means), np.array(floors)
    # Both neighbours together predict at least as well as one alone, on average...
    assert means.mean() <= floors.mean()
    # ...and no profile, the end ones included, is far worse than its own floor (with
    # the end rings cut at the estimated axis's ends, the first profile read 71 mm
    # against a 26 mm floor).
    assert (means <= 2.0 * floors + 0.005).all(), np.c_[means, floors]
