"""Rock relief of drill-and-blast galleries: the fields' statistics against their
parameters, the look-out sawtooth, the floor taper, bounds, determinism, independence
of the mesh, and a generated gallery: manifold, inward lining, labels, features sitting
on the relieved rock, control points at the moved prisms."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import norm

from survey.cli.main import main
from survey.errors import TunnelError
from survey.world import features as F
from survey.world.alignment import Alignment, curve, straight
from survey.world.generator import make_tunnel
from survey.world.mesh import LABEL
from survey.world.presets import preset
from survey.world.profiles import circle, horseshoe
from survey.world.rock import (OVERBREAK_CLIP, TEXTURE_CLIP, RockRelief, floor_weight,
                               surface_relief, texture_field)
from tests.naive import naive_cast, naive_point_mesh

PROFILE = horseshoe(2.8, 1.4)
GRID_LABELS = [LABEL[n] for n in ("lining", "floor", "wet_floor", "niche", "drainage")]


def _clipped_normal_moments(mu, sigma, lo, hi):
    """Mean and standard deviation of clip(N(mu, sigma^2), lo, hi), in closed form."""
    a, b = (lo - mu) / sigma, (hi - mu) / sigma
    pa, pb = norm.cdf(a), norm.cdf(b)
    da, db = norm.pdf(a), norm.pdf(b)
    # E[X 1(a<Z<b)] and E[X^2 1(a<Z<b)] for X = mu + sigma Z.
    m1 = mu * (pb - pa) + sigma * (da - db)
    m2 = (mu ** 2 + sigma ** 2) * (pb - pa) + 2 * mu * sigma * (da - db) + \
        sigma ** 2 * (a * da - b * db)
    mean = lo * pa + hi * (1 - pb) + m1
    second = lo ** 2 * pa + hi ** 2 * (1 - pb) + m2
    return mean, np.sqrt(second - mean ** 2)


# ---------------------------------------------------------------------- statistics
# Sampling tolerances. A stationary field with Gaussian autocorrelation
# rho(u) = exp(-|u|^2 / (2 L^2)) observed over an area A >> L^2 has (Bartlett's
# large-sample formulas, integrals over the plane in closed form for this rho):
#   var(sample mean)     = sigma^2 / A * int rho      = sigma^2 2 pi L^2 / A,
#   var(sample variance) = 2 sigma^4 / A * int rho^2  = 2 sigma^4 pi L^2 / A,
#                          so sd(sample sd) / sigma   = sqrt(pi L^2 / (2 A)),
#   var(rho_hat(d))      = pi L^2 / A * [1 + e^(-d^2/L^2) - 4 rho(d) e^(-d^2/(4 L^2))
#                                        + 2 rho(d)^2].
# The tests allow 4 standard errors (a fixed seed: pass or fail does not change, and a
# true model fails with probability ~6e-5). The bilinear interpolation between the grid
# nodes (L/8 apart) lowers the variance by < 0.5 %, far inside these tolerances.
L_SIGMA = 4.0


def _walls(relief, length_m=2000.0, ds=0.15, dt=0.12, seed=5):
    """Overbreak on the full-weight part of the walls (beyond the floor taper) of a long
    horseshoe gallery, sampled every ds along and dt around: (field (ns, nt), s (ns,),
    t (nt,), area m^2)."""
    s = np.arange(0.0, length_m + 1e-9, ds)
    t = np.arange(0.0, PROFILE.perimeter_m, dt)
    walls = floor_weight(PROFILE, t, relief.floor_taper_m) == 1.0
    f = relief.overbreak(PROFILE, s, t, 0.0, length_m, seed)[:, walls]
    tw = t[walls]
    return f, s, tw, length_m * (tw.max() - tw.min())


def _rho(x, lag, axis):
    x = x - x.mean()
    a = np.take(x, np.arange(x.shape[axis] - lag), axis=axis)
    b = np.take(x, np.arange(lag, x.shape[axis]), axis=axis)
    return float(np.mean(a * b) / np.mean(x * x))


def _rho_se(d, corr, area):
    r = np.exp(-d ** 2 / (2 * corr ** 2))
    br = 1 + np.exp(-d ** 2 / corr ** 2) - 4 * r * np.exp(-d ** 2 / (4 * corr ** 2)) + \
        2 * r ** 2
    return np.sqrt(np.pi * corr ** 2 / area * br)


def test_gaussian_overbreak_has_its_mean_rms_and_correlation_length():
    """Without look-out and with clipping out of reach, the wall overbreak is the
    Gaussian field itself: mean, rms and autocorrelation at lags L and 2L along the
    tunnel, and at L around the section, match the parameters within 4 standard errors
    (from the number of independent samples, see above)."""
    mu, sigma, corr = 0.07, 0.07, 1.2
    relief = RockRelief(overbreak_mean_m=mu, overbreak_rms_m=sigma, overbreak_corr_m=corr,
                        underbreak_max_m=1.0, lookout_m=0.0)
    f, s, t, area = _walls(relief)
    assert abs(f.mean() - mu) < L_SIGMA * sigma * np.sqrt(2 * np.pi * corr ** 2 / area)
    sd_tol = L_SIGMA * np.sqrt(np.pi * corr ** 2 / (2 * area)) + 0.005  # + interpolation
    assert abs(f.std() / sigma - 1) < sd_tol
    ds = s[1] - s[0]
    for d in (corr, 2 * corr):
        lag = int(round(d / ds))
        d_true = lag * ds
        expected = np.exp(-d_true ** 2 / (2 * corr ** 2))
        assert abs(_rho(f, lag, 0) - expected) < L_SIGMA * _rho_se(d_true, corr, area)
    # Around the section (the wall columns are one contiguous arc, 0.12 m apart).
    assert np.allclose(np.diff(t), 0.12)
    lag = int(round(corr / 0.12))
    expected = np.exp(-(lag * 0.12) ** 2 / (2 * corr ** 2))
    area_t = area * (len(t) - lag) / len(t)
    assert abs(_rho(f, lag, 1) - expected) < L_SIGMA * _rho_se(lag * 0.12, corr, area_t)
    # The measured correlation length, from rho_hat(L) = exp(-L^2 / (2 L_hat^2)).
    lag = int(round(corr / ds))
    l_hat = lag * ds / np.sqrt(-2 * np.log(_rho(f, lag, 0)))
    assert l_hat == pytest.approx(corr, rel=0.1)


def test_clipped_overbreak_mean_and_rms_follow_the_clipped_normal():
    """With the defaults' underbreak clip (2 cm, ~13 % of the wall area), the wall
    overbreak (look-out off) has the mean and spread of a clipped normal, computed in
    closed form; underbreak never exceeds the clip."""
    relief = replace(RockRelief(), lookout_m=0.0)
    f, _, _, area = _walls(relief)
    lo = -relief.underbreak_max_m
    hi = relief.overbreak_mean_m + OVERBREAK_CLIP * relief.overbreak_rms_m
    mean, sd = _clipped_normal_moments(relief.overbreak_mean_m, relief.overbreak_rms_m,
                                       lo, hi)
    sig, corr = relief.overbreak_rms_m, relief.overbreak_corr_m
    assert abs(f.mean() - mean) < L_SIGMA * sig * np.sqrt(2 * np.pi * corr ** 2 / area)
    assert abs(f.std() / sd - 1) < L_SIGMA * np.sqrt(np.pi * corr ** 2 / (2 * area)) + 0.005
    assert f.min() >= lo and f.max() <= hi
    assert np.mean(f == lo) == pytest.approx(norm.cdf((lo - relief.overbreak_mean_m) / sig),
                                             abs=0.03)


def test_rounds_tile_the_tunnel_with_jittered_lengths_and_lookouts():
    relief = RockRelief()
    starts, amps = relief.rounds(10.0, 310.0, seed=3)
    lengths = np.diff(starts)
    assert starts[0] <= 10.0 < starts[1] and starts[-2] < 310.0 <= starts[-1]
    assert len(amps) == len(lengths)
    L, j = relief.round_length_m, relief.round_jitter
    assert lengths.min() >= L * (1 - j) and lengths.max() <= L * (1 + j)
    a, ja = relief.lookout_m, relief.lookout_jitter
    assert amps.min() >= a * (1 - ja) and amps.max() <= a * (1 + ja)
    assert lengths.std() > 0.02 * L and amps.std() > 0.05 * a      # not periodic
    # The sawtooth: 0 one step into a round, the round's look-out at its end, linear
    # in between, and the step down from the previous round's look-out.
    step = relief.lookout_step_m
    b0, b1 = starts[1:-1], starts[2:]
    look = lambda x: relief.lookout(x, 10.0, 310.0, 3)            # noqa: E731
    np.testing.assert_allclose(look(b0 + step), 0.0, atol=1e-12)
    np.testing.assert_allclose(look(b1), amps[1:], atol=1e-12)
    np.testing.assert_allclose(look((b0 + step + b1) / 2), amps[1:] / 2, atol=1e-12)
    np.testing.assert_allclose(look(b0 + step / 2), amps[:-1] / 2, atol=1e-12)


def test_sawtooth_is_visible_in_the_mean_relief_across_a_round():
    """The wall relief (Gaussian part, clipping and look-out together) averaged by
    position within its round rises across the round by about the mean look-out: the
    Gaussian part averages out over the ~660 rounds of a 2 km gallery."""
    relief = RockRelief()
    f, s, _, _ = _walls(relief)
    starts, amps = relief.rounds(0.0, 2000.0, seed=5)
    k = np.searchsorted(starts, s, side="right") - 1
    frac = (s - starts[k]) / (starts[k + 1] - starts[k])
    ring_mean = f.mean(axis=1)
    bins = np.linspace(0.2, 1.0, 5)               # past the step down
    means = [ring_mean[(frac >= a) & (frac < b)].mean() for a, b in zip(bins, bins[1:])]
    assert np.all(np.diff(means) > 0)
    # Bin centres 0.3 and 0.9 of a round: the look-out grows by ~(0.9-0.3) x 10 cm
    # (the step takes 0.1 of a round: (x - 0.1) / 0.9 of the look-out at x).
    rise = (0.8 / 0.9 - 0.2 / 0.9) * amps.mean()
    assert means[-1] - means[0] == pytest.approx(rise, abs=0.01)


def test_no_overbreak_on_the_floor_and_full_overbreak_past_the_taper():
    relief = RockRelief()
    t = PROFILE.sample(0.02)
    w = floor_weight(PROFILE, t, relief.floor_taper_m)
    on_floor = PROFILE.is_floor(t)
    assert on_floor.sum() > 50 and np.all(w[on_floor] == 0)
    s = np.linspace(0.0, 30.0, 61)
    ob = relief.overbreak(PROFILE, s, t, 0.0, 30.0, seed=2)
    assert np.all(ob[:, on_floor] == 0)
    # Arc length from the floor's ends: the weight rises monotonically to 1 at the taper.
    t_floor_end = t[on_floor].max()
    up = (t > t_floor_end) & (t < t_floor_end + 0.5)
    assert np.all(np.diff(w[up]) >= 0)
    assert np.all(w[up & (t >= t_floor_end + relief.floor_taper_m + 0.02)] == 1.0)
    assert np.all(w[up & (t < t_floor_end + relief.floor_taper_m - 0.02)] < 1.0)


# ---------------------------------------------------------------------- bounds, seeds
@settings(max_examples=25, deadline=None)
@given(mean=st.floats(0.0, 0.3), rms=st.floats(0.0, 0.3), corr=st.floats(0.3, 3.0),
       under=st.floats(0.0, 0.2), lookout=st.floats(0.0, 0.4), jit=st.floats(0.0, 0.9),
       ljit=st.floats(0.0, 0.9), rl=st.floats(1.0, 6.0), tex=st.floats(0.0, 0.05),
       seed=st.integers(0, 2**31))
def test_relief_is_bounded_for_any_valid_parameters(mean, rms, corr, under, lookout, jit,
                                                    ljit, rl, tex, seed):
    relief = RockRelief(overbreak_mean_m=mean, overbreak_rms_m=rms, overbreak_corr_m=corr,
                        underbreak_max_m=under, lookout_m=lookout, round_jitter=jit,
                        lookout_jitter=ljit, round_length_m=rl,
                        lookout_step_m=0.2 * rl * (1 - jit), texture_rms_m=tex,
                        texture_corr_m=0.3)
    s = np.linspace(5.0, 25.0, 120)
    t = PROFILE.sample(0.2)
    ob = relief.overbreak(PROFILE, s, t, 5.0, 25.0, seed)
    assert np.isfinite(ob).all()
    assert ob.min() >= -under - 1e-12 and ob.max() <= relief.overbreak_max_m + 1e-12
    tot = surface_relief(PROFILE, s, t, 5.0, 25.0, texture_rms_m=tex, texture_corr_m=0.3,
                         relief=relief, seed=seed)
    assert tot.min() >= -under - TEXTURE_CLIP * tex - 1e-12
    assert tot.max() <= relief.overbreak_max_m + TEXTURE_CLIP * tex + 1e-12


def test_relief_is_deterministic_per_seed_and_differs_between_seeds():
    relief = RockRelief()
    s, t = np.linspace(0.0, 40.0, 201), PROFILE.sample(0.1)
    a = surface_relief(PROFILE, s, t, 0.0, 40.0, texture_rms_m=0.01, texture_corr_m=0.3,
                       relief=relief, seed=11)
    b = surface_relief(PROFILE, s, t, 0.0, 40.0, texture_rms_m=0.01, texture_corr_m=0.3,
                       relief=relief, seed=11)
    c = surface_relief(PROFILE, s, t, 0.0, 40.0, texture_rms_m=0.01, texture_corr_m=0.3,
                       relief=relief, seed=12)
    np.testing.assert_array_equal(a, b)
    assert np.sqrt(np.mean((a - c) ** 2)) > relief.overbreak_rms_m
    # The texture layer is the generator's roughness: the same surface for a seed with
    # or without the rock relief on top.
    np.testing.assert_allclose(
        a - relief.overbreak(PROFILE, s, t, 0.0, 40.0, 11),
        texture_field(s, t, 0.0, 40.0, PROFILE.perimeter_m, 0.01, 0.3, 11), atol=1e-15)


def test_relief_does_not_depend_on_the_mesh():
    """A coarse and a fine mesh of the same seed carry the same relieved surface: where
    their vertices coincide (every other ring and profile sample) they are identical."""
    al, prof = Alignment([straight(30.0)]), circle(2.0)
    h = prof.perimeter_m / 64
    coarse = make_tunnel(al, prof, edge_length_m=h, relief=RockRelief(), seed=7)
    fine = make_tunnel(al, prof, edge_length_m=h / 2, relief=RockRelief(), seed=7)
    vc = coarse.vertices.reshape(-1, 64, 3)
    vf = fine.vertices.reshape(-1, 128, 3)
    assert vf.shape[0] == 2 * vc.shape[0] - 1
    np.testing.assert_allclose(vf[::2, ::2], vc, atol=1e-12)
    smooth = make_tunnel(al, prof, edge_length_m=h, seed=7)
    assert np.abs(smooth.vertices - coarse.vertices).max() > 0.1     # the relief is there


# ---------------------------------------------------------------------- a gallery
def _alignment():
    return Alignment([straight(6.0), *curve(0.2, 40.0, 4.0), straight(6.0)],
                     heading_rad=0.3, profile=((0.0, 0.0), (20.0, 0.2)))


FEATURES = (F.Cable("left", 1.5, radius_m=0.02, start_m=1.0, end_m=19.0),
            F.Niche("right", 8.0, 9.5, 0.3, 1.9, depth_m=0.6),
            F.Drainage(-0.6, 0.3, 0.2),
            F.WetFloor(12.0, 16.0),
            F.Bolts((0.0, 0.6, -0.6), spacing_m=2.0, start_m=2.0, end_m=18.0),
            F.Prisms((4.0, 14.0), (1.2, 0.0, -1.2)))
H = 0.15


@pytest.fixture(scope="module")
def gallery():
    return make_tunnel(_alignment(), PROFILE, edge_length_m=H, features=FEATURES,
                       relief=RockRelief(), seed=4)


def _edges(faces):
    return np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])


def _design_normal_world(tun, s, t):
    """Outward design normals (n, 3) of the lining at chainages s, parameters t (the
    alignment is nearly level: 1 % grade)."""
    n2 = tun.profile.normals(t)
    th = tun.alignment.heading(s)
    return np.stack([-n2[:, 0] * np.sin(th), n2[:, 0] * np.cos(th), n2[:, 1]], 1)


def test_gallery_is_manifold_with_inward_lining_and_the_smooth_labels(gallery):
    e = _edges(gallery.faces)
    und, count = np.unique(np.sort(e, axis=1), axis=0, return_counts=True)
    assert set(np.unique(count)) <= {1, 2}
    assert len(np.unique(e, axis=0)) == len(e)
    c0, c1 = gallery.alignment.chainage_range
    s_border = gallery.vertex_chainage[und[count == 1].ravel()]
    assert np.all((np.abs(s_border - c0) < 1e-9) | (np.abs(s_border - c1) < 1e-9))
    mesh = trimesh.Trimesh(gallery.vertices, gallery.faces, process=False)
    assert mesh.is_winding_consistent
    # Every lining-grid triangle (recesses included) faces the tunnel: its normal has a
    # positive component along the design inward normal at its cell.
    grid = np.isin(gallery.labels, GRID_LABELS)
    f = gallery.faces[grid]
    tri = gallery.vertices[f]
    nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    s = gallery.vertex_chainage[f].mean(axis=1)
    tv = gallery.vertex_param[f]
    per = gallery.profile.perimeter_m
    tv = tv[:, :1] + np.mod(tv - tv[:, :1] + per / 2, per) - per / 2   # across t = 0
    inward = -_design_normal_world(gallery, s, tv.mean(axis=1))
    assert np.einsum("ij,ij->i", nrm, inward).min() > 0
    # The relief moves vertices only: faces and labels are the smooth gallery's.
    smooth = make_tunnel(_alignment(), PROFILE, edge_length_m=H, features=FEATURES,
                         roughness_rms_m=0.0, seed=4)
    np.testing.assert_array_equal(gallery.faces, smooth.faces)
    np.testing.assert_array_equal(gallery.labels, smooth.labels)
    assert gallery.metadata["face_counts"] == smooth.metadata["face_counts"]
    for name in ("lining", "floor", "wet_floor", "niche", "drainage", "cable", "bolt",
                 "prism"):
        assert gallery.metadata["face_counts"][name] > 0


def _offsets(tun, v):
    """Signed offsets (n,) of vertices v from the design lining along its outward
    normal at the vertex's own profile parameter."""
    s, off, h = tun.alignment.to_local(tun.vertices[v])
    t = tun.vertex_param[v]
    return np.einsum("ij,ij->i", np.stack([off, h], 1) - tun.profile.points(t),
                     tun.profile.normals(t))


def test_floor_carries_texture_only_and_recesses_stay_recessed(gallery):
    rough = RockRelief().texture_rms_m * TEXTURE_CLIP
    floor = np.unique(gallery.faces[np.isin(gallery.labels, [LABEL["floor"],
                                                             LABEL["wet_floor"]])])
    assert np.abs(_offsets(gallery, floor)).max() <= rough + 1e-9
    walls = np.unique(gallery.faces[gallery.labels == LABEL["lining"]])
    assert _offsets(gallery, walls).mean() > 0.08             # mostly overbreak
    # The back of the niche and the bottom of the channel lie their depth behind the
    # relieved surface: offset - depth is the relief field at the vertex's (s, t),
    # evaluated directly (the fields do not depend on the grid they are sampled on).
    c0, c1 = gallery.alignment.chainage_range
    for label, depth in ((LABEL["niche"], 0.6), (LABEL["drainage"], 0.2)):
        v = np.unique(gallery.faces[gallery.labels == label])
        d = _offsets(gallery, v)
        v, d = v[d > depth / 2], d[d > depth / 2]             # the back, not the sides
        su, iu = np.unique(gallery.vertex_chainage[v], return_inverse=True)
        tu, ju = np.unique(gallery.vertex_param[v], return_inverse=True)
        field = surface_relief(gallery.profile, su, tu, c0, c1, texture_rms_m=0.01,
                               texture_corr_m=0.3, relief=RockRelief(), seed=4)
        np.testing.assert_allclose(d - depth, field[iu, ju], atol=1e-9)


#: How far a point placed at the grid's relief, interpolated linearly in (chainage, t),
#: can lie from the flat mesh triangles at edge H: the chord sagitta H^2 / (8 R) on the
#: 1.4 m crown radius (2.0 mm), the same for the offset normals (reach 0.5 m x
#: H^2 / (8 R^2), 0.7 mm), and the relief's change across a cell (slope around the
#: section <= 0.25: 3.5 x the rms slope sqrt((0.07/1.2)^2 + (0.01/0.3)^2)) times the
#: turn of the normal across it (H / R), seen through that slope again (0.9 mm).
ON_ROCK_M = H ** 2 / (8 * 1.4) + 0.5 * H ** 2 / (8 * 1.4 ** 2) + 0.25 * H * H / 1.4 * 0.25


def _lining_faces_near(tun, s, margin=0.6):
    grid = np.isin(tun.labels, GRID_LABELS)
    f = tun.faces[grid]
    fs = tun.vertex_chainage[f].mean(axis=1)
    return f[np.abs(fs - s) < margin]


def test_prisms_stand_on_the_rock_and_are_the_control_points(gallery):
    cps = gallery.metadata["control_points"]
    assert len(cps) == 6
    prism_v = np.unique(gallery.faces[gallery.labels == LABEL["prism"]])
    pv = gallery.vertices[prism_v]
    for c in cps:
        xyz = np.array(c["xyz"])
        # The sphere of this prism is centred on the control point.
        r = np.linalg.norm(pv - xyz, axis=1)
        assert np.isclose(r, 0.03, atol=1e-9).sum() == 42
        # Its mounting point, standoff behind the centre along the design normal, lies
        # on the lining mesh (brute-force closest point on the nearby triangles).
        n = _design_normal_world(gallery, np.array([c["chainage_m"]]),
                                 np.array([c["profile_t_m"]]))[0]
        mount = xyz + 0.1 * n
        d, _ = naive_point_mesh(mount[None], gallery.vertices,
                                _lining_faces_near(gallery, c["chainage_m"]))
        assert d[0] < ON_ROCK_M
        # ... and it moved with the relief: the design point is relief_m behind it.
        s, off, h = gallery.alignment.to_local(mount[None])
        p = gallery.profile.points(c["profile_t_m"])
        assert np.hypot(off[0] - p[0], h[0] - p[1]) == pytest.approx(abs(c["relief_m"]),
                                                                      abs=1e-9)
    assert max(abs(c["relief_m"]) for c in cps) > 0.03        # the relief mattered


def test_bolt_plates_rest_on_the_rock_without_gaps(gallery):
    """Each plate's front face is its thickness proud of the rock at its centre, and
    behind each of its four front corners the rock surface is reached before the back
    of the plate: no gap under it."""
    v = gallery.faces[gallery.labels == LABEL["bolt"]]
    first = np.unique(v)[::8]                                 # boxes of 8 vertices
    assert len(first) > 20
    for b0 in first[:: max(1, len(first) // 15)]:
        box = gallery.vertices[b0:b0 + 8]                     # v = x + 2 u + 4 w
        front, back = box[4:], box[:4]                        # w = 1: into the tunnel
        out = back[0] - front[0]
        depth = np.linalg.norm(out)
        out /= depth
        faces = _lining_faces_near(gallery, gallery.vertex_chainage[b0])
        centre = front.mean(axis=0)
        hit, *_ = naive_cast(gallery.vertices, faces, centre[None], out[None])
        assert hit[0] == pytest.approx(0.02, abs=ON_ROCK_M)  # thickness
        hits, *_ = naive_cast(gallery.vertices, faces, front, np.broadcast_to(out, (4, 3)))
        assert np.all(hits < depth)


def test_cables_keep_their_gap_from_the_rock(gallery):
    v = np.unique(gallery.faces[gallery.labels == LABEL["cable"]])
    s = gallery.vertex_chainage[v]
    rings = np.unique(s)
    pick = rings[np.linspace(0, len(rings) - 1, 10).astype(int)]
    t = gallery.profile.t_at_height("left", 1.5)
    lifts = []
    for sr in pick:
        ring = gallery.vertices[v[(s == sr)]]
        ring = ring[np.linalg.norm(ring - ring.mean(axis=0), axis=1) > 1e-9]  # no cap
        ctr = ring.mean(axis=0)
        n = _design_normal_world(gallery, np.array([sr]), np.array([t]))[0]
        hit, *_ = naive_cast(gallery.vertices, _lining_faces_near(gallery, sr), ctr[None],
                             n[None])
        assert hit[0] == pytest.approx(0.03 + 0.02, abs=ON_ROCK_M)
        _, off, h = gallery.alignment.to_local(ctr[None])
        lifts.append(float(np.dot(np.array([off[0], h[0]]) - gallery.profile.points(t),
                                  gallery.profile.normals(t))))
    assert np.ptp(lifts) > 0.02                               # it follows the relief


def test_closed_gallery_with_relief_is_watertight():
    feats = [f for f in FEATURES if not isinstance(f, F.Drainage)]
    tun = make_tunnel(_alignment(), PROFILE, edge_length_m=0.2, features=feats,
                      relief=RockRelief(), closed_ends=True, seed=1)
    mesh = trimesh.Trimesh(tun.vertices, tun.faces, process=False)
    assert mesh.is_watertight and mesh.is_winding_consistent


def test_relief_reach_guards_tight_curves():
    """A curve the smooth lining fits but the overbreak would fold is refused."""
    al = Alignment([straight(5.0), *curve(1.0, 2.5, 0.5)])
    make_tunnel(al, PROFILE, edge_length_m=0.2, roughness_rms_m=0.0)
    with pytest.raises(TunnelError, match="fold on the inside"):
        make_tunnel(al, PROFILE, edge_length_m=0.2, relief=RockRelief().scaled(4.0))


# ---------------------------------------------------------------------- presets, CLI
def test_bfo_has_rock_relief_and_tbm_stays_smooth():
    bfo, _ = preset("bfo", edge_length_m=0.5)
    tbm, _ = preset("tbm", edge_length_m=0.5)
    assert bfo.metadata["parameters"]["relief"] == RockRelief().to_dict()
    assert bfo.metadata["parameters"]["roughness_rms_m"] == RockRelief().texture_rms_m
    assert tbm.metadata["parameters"]["relief"] is None
    assert tbm.metadata["parameters"]["roughness_rms_m"] == 0.002
    old, _ = preset("bfo", edge_length_m=0.5, relief=None)
    assert old.metadata["parameters"]["roughness_rms_m"] == 0.003
    rough, _ = preset("bfo", edge_length_m=0.5, roughness_rms_m=0.05)
    assert rough.metadata["parameters"]["roughness_rms_m"] == 0.05
    assert rough.metadata["parameters"]["relief"] == RockRelief().to_dict()


def test_cli_switches_and_scales_the_relief(tmp_path):
    out = tmp_path / "t.ply"
    assert main(["tunnel", "-o", str(out), "--preset", "tbm", "--edge-length", "0.5",
                 "--relief", "rock", "--relief-scale", "0.5", "--quiet"]) == 0
    rel = json.loads(out.with_suffix(".json").read_text())["parameters"]["relief"]
    assert rel == RockRelief().scaled(0.5).to_dict()
    assert rel["overbreak_rms_m"] == pytest.approx(0.5 * RockRelief().overbreak_rms_m)
    assert main(["tunnel", "-o", str(out), "--preset", "bfo", "--edge-length", "0.5",
                 "--relief", "none", "--roughness-mm", "100", "--quiet"]) == 0
    par = json.loads(out.with_suffix(".json").read_text())["parameters"]
    assert par["relief"] is None and par["roughness_rms_m"] == pytest.approx(0.1)
    assert main(["tunnel", "-o", str(out), "--preset", "tbm", "--relief-scale", "2",
                 "--quiet"]) == 2


# ---------------------------------------------------------------------- bad input
@pytest.mark.parametrize("kwargs, match", [
    ({"overbreak_rms_m": -0.1}, "`overbreak_rms_m` to be a number >= 0"),
    ({"lookout_m": float("nan")}, "`lookout_m` to be a number >= 0"),
    ({"round_jitter": 1.0}, "`round_jitter` below 1"),
    ({"lookout_jitter": 1.5}, "`lookout_jitter` below 1"),
    ({"overbreak_corr_m": 0.0}, "positive `overbreak_corr_m`"),
    ({"texture_corr_m": 0.0}, "positive `texture_corr_m`"),
    ({"lookout_step_m": 2.0}, "`lookout_step_m` in"),
    ({"floor_taper_m": "a"}, "`floor_taper_m` to be a number"),
])
def test_bad_relief(kwargs, match):
    with pytest.raises(TunnelError, match=match):
        RockRelief(**kwargs)


def test_bad_relief_elsewhere():
    with pytest.raises(TunnelError, match="scale factor >= 0"):
        RockRelief().scaled(-1.0)
    with pytest.raises(TunnelError, match="RockRelief fields"):
        RockRelief.from_dict({"overbreak_m": 0.1})
    assert RockRelief.from_dict(RockRelief().to_dict()) == RockRelief()
    with pytest.raises(TunnelError, match="`relief` as a RockRelief or None"):
        make_tunnel(_alignment(), PROFILE, relief={"overbreak_mean_m": 0.1})
    with pytest.raises(TunnelError, match="`relief` as 'preset', None or a RockRelief"):
        preset("bfo", relief="rock")
