"""Rings (issue 17, item 2): geometric circle and ellipse fits against closed forms,
a noisy synthetic ellipse, a cut mesh, outliers, bad input and the ``rings`` command."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from survey.analysis.rings import fit_circle, fit_ellipse, fit_rings
from survey.analysis.sections import SectionCut, cut_mesh
from survey.cli.main import main
from survey.errors import CompareError
from survey.world.alignment import Alignment, straight
from survey.world.generator import make_tunnel
from survey.world.profiles import circle


def _ellipse_points(c, a, b, th, phi):
    r = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    p = c + (r @ np.stack([a * np.cos(phi), b * np.sin(phi)])).T
    n = (r @ np.stack([b * np.cos(phi), a * np.sin(phi)])).T
    return p, n / np.linalg.norm(n, axis=1)[:, None]


def test_circle_closed_forms():
    # Three points: the circumscribed circle (centre (1, 1), radius sqrt 2).
    f = fit_circle([[0, 0], [2, 0], [0, 2]], reject_sigma=None)
    assert np.allclose(f.centre, [1, 1], atol=1e-12) and f.radius_m == pytest.approx(2 ** 0.5)
    # Radii alternating 2.0 / 2.2 at 30 deg steps: by symmetry the centre stays put;
    # the geometric radius is then the mean radius 2.1, Kasa's algebraic one
    # sqrt(mean r^2) = 2.10238 (what tells the two fits apart).
    ang = np.arange(12) * np.pi / 6
    r = np.where(np.arange(12) % 2 == 0, 2.0, 2.2)
    f = fit_circle(np.stack([r * np.cos(ang) + 5, r * np.sin(ang) + 7], 1),
                   reject_sigma=None)
    assert np.allclose(f.centre, [5, 7], atol=1e-12)
    assert f.radius_m == pytest.approx(2.1, abs=1e-12)
    assert f.algebraic[2] == pytest.approx(np.sqrt(np.mean(r ** 2)), abs=1e-12)


def test_exact_ellipse_is_recovered_exactly():
    p, _ = _ellipse_points(np.array([3.0, -2.0]), 2.9, 2.6, 1.1,
                           np.linspace(0, 2 * np.pi, 50, endpoint=False))
    f = fit_ellipse(p, reject_sigma=None)
    assert np.allclose(f.centre, [3, -2], atol=1e-9)
    assert (f.a_m, f.b_m, f.angle_rad) == pytest.approx((2.9, 2.6, 1.1), abs=1e-9)
    assert f.rms_m < 1e-9


def test_noisy_ellipse_to_half_a_millimetre():
    # 3000 points with 2 mm of noise along the normal: each parameter scatters by
    # about sigma * sqrt(2 / n) ~ 0.05 mm, so 0.5 mm is ten standard deviations
    # (and well inside the acceptance).
    rng = np.random.default_rng(11)
    c, a, b, th = np.array([0.012, 2.75]), 2.76, 2.71, 0.4
    p, n = _ellipse_points(c, a, b, th, rng.uniform(0, 2 * np.pi, 3000))
    p = p + n * rng.normal(0, 0.002, (len(p), 1))
    f = fit_ellipse(p)
    assert np.abs(f.centre - c).max() <= 5e-4
    assert abs(f.a_m - a) <= 5e-4 and abs(f.b_m - b) <= 5e-4
    assert f.rms_m == pytest.approx(0.002, rel=0.1)
    assert f.ovality() == pytest.approx(2 * (a - b) / (a + b), abs=4e-4)
    # The algebraic start alone is biased by noise; the geometric fit is not worse.
    assert abs(f.a_m - a) <= abs(f.algebraic[2] - a) + 1e-5


def test_outliers_are_dropped():
    rng = np.random.default_rng(2)
    p, n = _ellipse_points(np.zeros(2), 2.5, 2.45, 0.0, rng.uniform(0, 2 * np.pi, 2000))
    p = p + n * rng.normal(0, 0.001, (len(p), 1))
    cable = np.stack([np.full(80, 2.35), np.linspace(0.3, 0.5, 80)], 1)  # inside
    f = fit_ellipse(np.vstack([p, cable]))
    assert abs(f.a_m - 2.5) < 5e-4 and abs(f.b_m - 2.45) < 5e-4
    assert fit_circle(np.vstack([p, cable])).radius_m == pytest.approx(2.475, abs=1e-3)


def test_rings_of_a_cut_mesh():
    al = Alignment([straight(10.0)], start_xy=(600_000.0, 5_200_000.0), heading_rad=0.7)
    tun = make_tunnel(al, circle(2.5), edge_length_m=0.05, roughness_rms_m=0.0)
    rings = fit_rings(cut_mesh(tun.vertices, tun.faces, al, [3.0, 7.0]),
                      reference_centre=(0.0, 2.5), nominal_diameter_m=5.0)
    for r in rings:
        # Mesh chords of 5 cm lie up to h^2 / (8 R) = 0.125 mm inside the circle.
        assert r.circle.diameter_m == pytest.approx(5.0, abs=3e-4)
        assert np.abs(r.centre_offset_m).max() < 1e-4
        assert r.ovality < 1e-4


def test_bad_ring_input():
    with pytest.raises(CompareError, match="at least 6"):
        fit_ellipse(np.zeros((5, 2)))
    with pytest.raises(CompareError, match="collinear"):
        fit_circle(np.stack([np.arange(10.0), 2 * np.arange(10.0)], 1))
    with pytest.raises(CompareError, match="at least 6 points in the section band"):
        fit_rings([SectionCut(5.0, 0.1, np.zeros((2, 2)), 2)])


def test_cli_rings_artefacts(tbm_mesh, tmp_path):
    out = tmp_path / "rings"
    assert main(["rings", str(tbm_mesh(0.1)), "--at", "30,50", "--min-height", "0.5",
                 "--nominal-diameter", "5", "-o", str(out), "--quiet"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["rings.csv", "rings.html", "rings.json",
                                                     "rings.md", "rings.png"]
    rows = list(csv.DictReader(open(out / "rings.csv")))
    assert [float(r["chainage_m"]) for r in rows] == [30.0, 50.0]
    for r in rows:
        assert float(r["circle_diameter_m"]) == pytest.approx(5.0, abs=2e-3)
    assert "| 30.000 |" in (out / "rings.md").read_text()
    assert (out / "rings.png").read_bytes()[:4] == b"\x89PNG"
