"""Deformation epochs: the displacement at sampled chainages equals the configured
field, computed here from its definition; features move with their lining point."""

from __future__ import annotations

import numpy as np
import pytest

from survey.world import features as F
from survey.world.alignment import Alignment, curve, straight
from survey.world.deformation import Bulge, Convergence, Ovalisation, from_dict, to_dict
from survey.errors import DeformationError
from survey.world.profiles import horseshoe
from survey.world.mesh import LABEL
from survey.errors import TunnelError
from survey.world.generator import make_tunnel
from tests.iofiles import mesh_fields as read_ply


@pytest.fixture(scope="module")
def base():
    al = Alignment([straight(20.0), *curve(0.2, 80.0, 6.0), straight(10.0)], heading_rad=1.0)
    return make_tunnel(al, horseshoe(2.8), edge_length_m=0.1, roughness_rms_m=0.002,
                       features=[F.Prisms((15.0, 30.0), (1.0, -1.0)),
                                 F.Cable("left", 1.5, start_m=1.0, end_m=40.0)], seed=2)


def _expected_convergence(s, start, end, value, taper):
    """Independent statement of the documented window: half-cosine ramps inside."""
    out = np.zeros_like(s)
    for i, x in enumerate(s):
        if start <= x <= end:
            w = 1.0
            if x < start + taper:
                w = min(w, (1 - np.cos(np.pi * (x - start) / taper)) / 2)
            if x > end - taper:
                w = min(w, (1 - np.cos(np.pi * (end - x) / taper)) / 2)
            out[i] = value * w
    return out


def _inward(tun, idx):
    """Inward unit normal of the design profile at each vertex, in world axes."""
    n2 = tun.profile.normals(tun.vertex_param[idx])
    th = tun.alignment.heading(tun.vertex_chainage[idx])
    return -np.stack([-n2[:, 0] * np.sin(th), n2[:, 0] * np.cos(th), n2[:, 1]], 1)


def test_convergence_equals_the_configured_field(base):
    conv = Convergence(12.0, 28.0, 0.005, taper_m=4.0)
    ep = base.deformed([conv])
    lining = np.zeros(len(base.vertices), bool)
    lining[base.faces[np.isin(base.labels, [LABEL["lining"], LABEL["floor"]])].ravel()] = True
    for s in (5.0, 12.0, 13.0, 14.0, 16.0, 20.0, 25.5, 28.0, 35.0):
        idx = np.nonzero(lining & np.isclose(base.vertex_chainage, s, atol=1e-9))[0]
        assert len(idx) > 50, s
        d = ep.vertices[idx] - base.vertices[idx]
        want = _expected_convergence(np.array([s]), 12.0, 28.0, 0.005, 4.0)[0]
        np.testing.assert_allclose(np.einsum("ij,ij->i", d, _inward(base, idx)), want,
                                   atol=1e-12)
        np.testing.assert_allclose(np.linalg.norm(d, axis=1), want, atol=1e-12)
    np.testing.assert_allclose(ep.displacement, ep.vertices - base.vertices, atol=1e-12)
    assert ep.metadata["deformation"] == [to_dict(conv)]


def test_features_move_rigidly_with_their_lining_point(base):
    conv = Convergence(10.0, 20.0, 0.004, taper_m=2.0)
    ep = base.deformed([conv])
    cps0, cps1 = base.metadata["control_points"], ep.metadata["control_points"]
    for a, b in zip(cps0, cps1):
        shift = np.linalg.norm(np.subtract(b["xyz"], a["xyz"]))
        want = _expected_convergence(np.array([a["chainage_m"]]), 10.0, 20.0, 0.004, 2.0)[0]
        assert shift == pytest.approx(want, abs=1e-12)
    prism = np.unique(base.faces[base.labels == LABEL["prism"]].ravel())
    d = ep.displacement[prism]
    at15 = np.isclose(base.vertex_chainage[prism], 15.0)   # the left prism at 15 m:
    at15 &= base.vertex_param[prism] == base.vertex_param[prism][at15][0]
    np.testing.assert_allclose(d[at15], d[at15][:1].repeat(at15.sum(), 0), atol=1e-15)
    assert np.linalg.norm(d[at15][0]) == pytest.approx(0.004, abs=1e-12)


def test_ovalisation_and_bulge_follow_their_formulas(base):
    prof = base.profile
    ov = Ovalisation(0.0, 50.0, 0.003, axis_rad=0.0, taper_m=0.0)
    bu = Bulge(30.0, 0.5, 1.0, 0.01)
    ep = base.deformed([ov, bu])
    idx = np.nonzero(np.isclose(base.vertex_chainage, 20.0) & np.isfinite(base.vertex_param))[0]
    idx = idx[:len(idx) // 2 * 2]
    p = prof.points(base.vertex_param[idx]) - prof.centroid
    phi = np.arctan2(p[:, 0], p[:, 1])
    want = 0.003 * np.cos(2 * phi)                 # s = 20 is 10 m from the bulge
    got = np.einsum("ij,ij->i", ep.vertices[idx] - base.vertices[idx], _inward(base, idx))
    lining = np.isin(idx, base.faces[base.labels == LABEL["lining"]].ravel())
    np.testing.assert_allclose(got[lining], want[lining], atol=1e-12)
    # The bulge's peak: the lining vertex nearest its centre moves by ~its amplitude.
    t0 = prof.t_at_angle(0.5)
    lin = np.isfinite(base.vertex_param)
    r = np.hypot(base.vertex_chainage - 30.0,
                 np.mod(base.vertex_param - t0 + prof.perimeter_m / 2, prof.perimeter_m)
                 - prof.perimeter_m / 2)
    r[~lin] = np.inf
    j = np.argmin(r)
    want_j = 0.01 * 0.5 * (1 + np.cos(np.pi * r[j] / 1.0)) + \
        0.003 * np.cos(2 * np.arctan2(*(prof.points(base.vertex_param[j]) - prof.centroid)))
    got_j = np.dot(ep.vertices[j] - base.vertices[j], _inward(base, np.array([j]))[0])
    assert got_j == pytest.approx(want_j, abs=1e-12)
    far = np.nonzero(np.isclose(base.vertex_chainage, 45.0) & lin)[0]
    assert np.abs(ep.displacement[far]).max() < 0.003 + 1e-12


def test_epoch_file_records_the_displacement(base, tmp_path):
    ep = base.deformed([Convergence(12.0, 28.0, 0.005)])
    ply, js = ep.write(tmp_path / "e2.ply")
    back = read_ply(ply)
    np.testing.assert_allclose(np.stack([back["dx"], back["dy"], back["dz"]], 1),
                               ep.displacement, atol=1e-9)   # float32 of mm values
    assert '"deformation"' in js.read_text()


def test_round_trip_and_bad_deformations():
    for d in (Convergence(1, 9, 0.01, 2), Ovalisation(0, 10, 0.002, 0.3, 1), Bulge(3, 0.2, 1, 0.01)):
        assert from_dict(to_dict(d)) == d
    with pytest.raises(DeformationError, match="end_m > start_m"):
        Convergence(10.0, 5.0, 0.005)
    with pytest.raises(DeformationError, match="taper_m"):
        Convergence(0.0, 4.0, 0.005, taper_m=3.0)
    with pytest.raises(DeformationError, match="radius_m"):
        Bulge(1.0, 0.0, 0.0, 0.01)
    with pytest.raises(DeformationError, match="kind"):
        from_dict({"kind": "twist"})


def test_deformed_rejects_other_objects(base):
    with pytest.raises(TunnelError, match="Convergence"):
        base.deformed(["5 mm"])
