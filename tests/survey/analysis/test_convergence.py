"""Convergence between epochs (survey.analysis.convergence) on a generated circular
tunnel with known deformations: chord changes against the closed form 2 f sin(dphi/2)
for prisms on a circle that converges by f, radial changes against the configured
fields."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from survey.analysis.convergence import (
    chords,
    control_points,
    radial_change,
    section_pairs,
    sections_every,
    summarise,
)
from survey.errors import CompareError
from survey.world import features as F
from survey.world.alignment import Alignment, straight
from survey.world.deformation import Bulge, Convergence
from survey.world.generator import make_tunnel
from survey.world.mesh import LABEL
from survey.world.profiles import circle

UTM = np.array([500_000.0, 5_000_000.0, 300.0])
ANGLES = (0.0, 1.2, -1.2)


@pytest.fixture(scope="module")
def tunnel():
    al = Alignment([straight(24.0)], start_xy=UTM[:2], heading_rad=0.7,
                   profile=((0.0, UTM[2]),))
    prof = circle(3.0)
    tun = make_tunnel(al, prof, edge_length_m=0.1, seed=1,
                      features=[F.Prisms((8.0, 12.0), ANGLES)])
    return al, prof, tun


def _lining(mesh):
    idx = np.unique(mesh.faces[mesh.labels == LABEL["lining"]].ravel())
    return mesh.vertices[idx]


def test_chords_equal_the_closed_form_for_a_converging_circle(tunnel):
    al, prof, tun = tunnel
    ep = tun.deformed([Convergence(4.0, 20.0, 0.005, taper_m=2.0)])
    cp = control_points(tun.metadata)
    res = chords(cp, control_points(ep.metadata), alignment=al, sigma_m=0.001)
    assert len(res) == 6          # three prisms per section, two sections
    # Prisms at radius rho_i about the axis and angles phi_i; convergence f moves each
    # to rho_i - f: L^2 = ra^2 + rb^2 - 2 ra rb cos(dphi) before and after.
    _, off, h = al.to_local(np.stack([cp[k] for k in sorted(cp)]))
    rho = dict(zip(sorted(cp), np.hypot(off - prof.centroid[0], h - prof.centroid[1])))
    phi = dict(zip(sorted(cp), ANGLES * 2))

    def length(ra, rb, d):
        return np.sqrt(ra * ra + rb * rb - 2 * ra * rb * np.cos(d))

    for row in res.rows():
        a, b = row["id_a"], row["id_b"]
        d = phi[a] - phi[b]
        want = length(rho[a], rho[b], d) - length(rho[a] - 0.005, rho[b] - 0.005, d)
        assert row["length1_m"] == pytest.approx(length(rho[a], rho[b], d), abs=1e-9)
        assert row["convergence_m"] == pytest.approx(want, abs=1e-9)
        assert want == pytest.approx(2 * 0.005 * np.sin(abs(d) / 2), abs=1e-5)
        assert row["lod_m"] == pytest.approx(1.96 * 2 * 0.001)
        assert row["significant"] == (want > 1.96 * 2 * 0.001)
        assert row["chainage_m"] == pytest.approx(8.0 if a < "P004" else 12.0, abs=1e-6)


def test_section_pairs_group_by_chainage(tunnel):
    al, _, tun = tunnel
    pairs = section_pairs(control_points(tun.metadata), al)
    assert pairs == [("P001", "P002"), ("P001", "P003"), ("P002", "P003"),
                     ("P004", "P005"), ("P004", "P006"), ("P005", "P006")]


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32 - 1),
       offset=st.tuples(st.floats(-3e6, 3e6), st.floats(0, 1e7), st.floats(-500, 3000)))
def test_chords_are_invariant_under_rigid_motion(seed, offset):
    rng = np.random.default_rng(seed)
    a = {f"P{i}": rng.uniform(-5, 5, 3) for i in range(4)}
    b = {k: v + rng.normal(0, 0.003, 3) for k, v in a.items()}
    rot = Rotation.random(random_state=seed)
    t = np.asarray(offset)
    pairs = [("P0", "P1"), ("P1", "P3"), ("P2", "P0")]
    r0 = chords(a, b, pairs)
    r1 = chords({k: rot.apply(v) + t for k, v in a.items()},
                {k: rot.apply(v) + t for k, v in b.items()}, pairs)
    np.testing.assert_allclose(r1.convergence_m, r0.convergence_m, atol=1e-8)
    np.testing.assert_allclose(r0.length1_m, [np.linalg.norm(a[x] - a[y])
                                              for x, y in pairs], rtol=1e-14)


def test_radial_change_recovers_convergence_noise_free_and_noisy(tunnel):
    al, prof, tun = tunnel
    ep = tun.deformed([Convergence(4.0, 20.0, 0.005, taper_m=2.0)])
    p1, p2 = _lining(tun), _lining(ep)
    out = radial_change(p1, p2, al, [6.0, 12.0, 22.5], centre=prof.centroid)
    for rc in out[:2]:
        ok = np.isfinite(rc.change_m)
        assert ok.sum() >= 60
        assert np.abs(rc.change_m[ok] - 0.005).max() < 1e-4        # noise-free
    assert np.nanmax(np.abs(out[2].change_m)) < 1e-4                 # outside the window
    # Realistic noise: 2 mm per coordinate (ASSUMED: a mobile scanner's figure).
    rng = np.random.default_rng(1)
    q1, q2 = (p + rng.normal(0, 0.002, p.shape) for p in (p1, p2))
    noisy = radial_change(q1, q2, al, [12.0, 22.5], centre=prof.centroid)
    ok = np.isfinite(noisy[0].change_m)
    assert noisy[0].significant[ok].mean() > 0.9
    assert abs(np.median(noisy[0].change_m[ok]) - 0.005) < 5e-4
    assert noisy[1].significant.mean() < 0.15                        # no change there
    rows = summarise(noisy)
    assert rows[0]["chainage_m"] == 12.0 and rows[0]["significant"] > 60


def test_radial_change_places_a_bulge_at_its_angle(tunnel):
    al, prof, tun = tunnel
    ep = tun.deformed([Bulge(12.0, 0.8, 1.0, 0.01)])
    rc = radial_change(_lining(tun), _lining(ep), al, [12.0], centre=prof.centroid,
                       band_m=0.1)[0]
    k = int(np.nanargmax(rc.change_m))
    assert rc.angle_rad[k] == pytest.approx(0.8, abs=np.deg2rad(5.0))
    assert rc.change_m[k] == pytest.approx(0.01, abs=1e-3)


def test_sections_every_and_errors(tunnel):
    al, prof, tun = tunnel
    np.testing.assert_allclose(sections_every(al, 5.0, margin_m=2.0), [5, 10, 15, 20])
    p = _lining(tun)
    with pytest.raises(CompareError, match=r"within the alignment \[0, 24\]"):
        radial_change(p, p, al, [30.0])
    with pytest.raises(CompareError, match="positive `band_m`"):
        radial_change(p, p, al, [5.0], band_m=0.0)
    with pytest.raises(CompareError, match="angle_step_rad"):
        radial_change(p, p, al, [5.0], angle_step_rad=0.0)
    with pytest.raises(CompareError, match="Expected points of epoch 2 within"):
        radial_change(p, p[:10], al, [20.0], band_m=0.05)
    cp = control_points(tun.metadata)
    with pytest.raises(CompareError, match="'P009' of chord P001-P009 in epoch 1"):
        chords(cp, cp, [("P001", "P009")])
    with pytest.raises(CompareError, match="`pairs` or an `alignment`"):
        chords(cp, cp)
    with pytest.raises(CompareError, match="'control_points'"):
        control_points({})
    with pytest.raises(CompareError, match="sigma_m"):
        chords(cp, cp, [("P001", "P002")], sigma_m=-1.0)


def test_cli_reports_chords_and_sections(tmp_path, capsys):
    import json

    from survey.cli.main import main

    t, t2 = tmp_path / "t.ply", tmp_path / "t2.ply"
    assert main(["tunnel", "--preset", "tbm", "--edge-length", "0.1", "-o", str(t),
                 "--epoch2", str(t2), "--quiet"]) == 0
    out = tmp_path / "conv"
    assert main(["convergence", str(t), str(t2), "--tunnel", str(t.with_suffix(".json")),
                 "--control1", str(t.with_suffix(".json")), "--control2",
                 str(t2.with_suffix(".json")), "--at", "20,50", "--sigma-mm", "1",
                 "-o", str(out), "--quiet"]) == 0
    summ = json.loads((out / "convergence.json").read_text())
    deform = json.loads(t2.with_suffix(".json").read_text())["deformation"][0]
    inside = [c for c in summ["chords"]
              if deform["start_m"] + deform["taper_m"] <= c["chainage_m"]
              <= deform["end_m"] - deform["taper_m"]]
    assert inside and all(c["significant"] and c["convergence_m"] > 0 for c in inside)
    sec = {round(s["chainage_m"]): s for s in summ["sections"]}
    assert abs(sec[20]["median_m"]) < 1e-4
    assert sec[50]["median_m"] == pytest.approx(deform["displacement_m"], abs=5e-4)
    for f in ("convergence.md", "chords.csv", "radial.csv", "radial.png"):
        assert (out / f).is_file()
    assert main(["convergence", str(t), "--tunnel", str(t.with_suffix(".json")),
                 "--at", "20", "-o", str(tmp_path / "c2"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Expected two epochs (earlier, later) or none, got 1" in err[0]
    assert not (tmp_path / "c2").exists()
