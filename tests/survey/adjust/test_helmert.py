"""Helmert adjustment against PROJ (pyproj), exact recovery, statistics, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from survey.errors import ControlPointError
from survey.adjust.controlpoints import ControlPoints, match, read_control_points
from survey.adjust.helmert import fit_helmert, from_parameters
from survey.adjust.helmert_stats import rotation_matrix
from survey.errors import HelmertError

UTM = np.array([451_000.0, 5_352_000.0, 600.0])
PARAMS = dict(t=(12.3, -4.5, 0.7), r=(3.2, -1.7, 12.5), s=15.3)


def _pts(n=12, seed=0):
    return np.random.default_rng(seed).uniform(-150, 150, (n, 3)) * [1, 1, 0.1] + UTM


def _proj(src, conv, exact):
    t, r, s = PARAMS["t"], PARAMS["r"], PARAMS["s"]
    pipe = (f"+proj=helmert +x={t[0]} +y={t[1]} +z={t[2]} +rx={r[0]} +ry={r[1]} +rz={r[2]} "
            f"+s={s} +convention={conv}" + (" +exact" if exact else ""))
    # PROJ is the reference; without pyproj (an extra) the comparisons skip, the rest runs.
    Transformer = pytest.importorskip("pyproj", reason="the PROJ reference needs pyproj "
                                      "(pip install 'tunnelsim[crs]')").Transformer
    return np.array(Transformer.from_pipeline(pipe).transform(*src.T)).T


@pytest.mark.parametrize("conv", ["position_vector", "coordinate_frame"])
@pytest.mark.parametrize("exact", [True, False])
def test_apply_matches_proj(conv, exact):
    src = _pts()
    h = from_parameters(PARAMS["t"], PARAMS["r"], PARAMS["s"], convention=conv)
    np.testing.assert_allclose(h.apply(src, exact=exact), _proj(src, conv, exact), atol=1e-6,
                               rtol=0)


@pytest.mark.parametrize("conv", ["position_vector", "coordinate_frame"])
def test_fit_recovers_proj_parameters(conv):
    src = _pts()
    res = fit_helmert(src, _proj(src, conv, True))
    want_r = np.array(PARAMS["r"])
    got_r = res.rotation_arcsec if conv == "position_vector" else res.rotation_arcsec_cf
    # PROJ's output carries float64 rounding at UTM size (~1e-9 m); over a 300 m
    # network that limits the recoverable scale and rotations to ~1e-5 ppm / arcsec,
    # i.e. far below a micrometre at the points. Tolerances 1e-4 ppm and arcsec.
    np.testing.assert_allclose(got_r, want_r, atol=1e-4)
    assert res.scale_ppm == pytest.approx(PARAMS["s"], abs=1e-4)
    np.testing.assert_allclose(res.apply(src), _proj(src, conv, True), atol=1e-6, rtol=0)
    if conv == "position_vector":
        # The translation acts at the origin, 5000 km from the points: the 1e-5
        # arcsec rotation noise above moves it by ~1e-5 m.
        np.testing.assert_allclose(res.translation_m, PARAMS["t"], atol=1e-4)
    Transformer = pytest.importorskip("pyproj", reason="the PROJ reference needs pyproj "
                                      "(pip install 'tunnelsim[crs]')").Transformer
    back = Transformer.from_pipeline(res.to_proj()).transform(*src.T)
    np.testing.assert_allclose(np.array(back).T, res.apply(src), atol=1e-6, rtol=0)


@pytest.mark.parametrize("angles", [(0, 0, np.pi), (np.pi, 0, 0), (0.3, -1.2, 2.9),
                                    (2.0, 1.4, -3.0)])
@pytest.mark.parametrize("model", ["7", "6"])
def test_noise_free_large_rotations_are_recovered_exactly(angles, model):
    src = _pts(8, seed=3)
    r = rotation_matrix(*angles)
    sc = 1.0 if model == "6" else 1.000123
    dst = np.array([10.0, -20.0, 5.0]) + sc * src @ r.T
    res = fit_helmert(src, dst, model=model)
    np.testing.assert_allclose(res.rotation_matrix, r, atol=1e-12)
    np.testing.assert_allclose(res.apply(src), dst, atol=1e-8, rtol=0)
    assert np.abs(res.residuals).max() < 1e-8


def test_reflection_is_refused_or_not_fitted():
    """Mirrored target: refused (issue 21); with allow_reflection the closed form must
    still not return a reflection (det R = +1)."""
    src = _pts(10, seed=4)
    dst = src * [1, -1, 1]
    with pytest.raises(HelmertError, match="mirror images"):
        fit_helmert(src, dst)
    res = fit_helmert(src, dst, allow_reflection=True)
    assert np.linalg.det(res.rotation_matrix) == pytest.approx(1.0)
    assert np.abs(res.residuals).max() > 1.0      # a rotation cannot fit a mirror image


def test_nine_parameter_model_recovers_axis_scales():
    src = _pts(10, seed=5)
    r = rotation_matrix(0.01, -0.02, 0.5)
    s = np.array([100.0, -50.0, 20.0])
    dst = [1.0, 2.0, 3.0] + (src * (1 + s * 1e-6)) @ r.T
    res = fit_helmert(src, dst, model="9")
    np.testing.assert_allclose(res.scale_ppm, s, atol=1e-5)
    np.testing.assert_allclose(res.apply(src), dst, atol=1e-8, rtol=0)


def test_sigma0_is_one_within_its_confidence_interval():
    """Known sigma: over 200 seeded trials sigma0^2 * r ~ chi^2(r); its mean is r and
    the empirical 95 % band of sigma0 matches the chi-square one."""
    rng = np.random.default_rng(11)
    src = _pts(10, seed=6)
    dst0 = _proj(src, "position_vector", True)
    s0 = []
    for _ in range(200):
        res = fit_helmert(src, dst0 + rng.normal(0, 0.002, src.shape), sigma_target_m=0.002)
        s0.append(res.sigma0)
    r = 3 * 10 - 7
    stat = np.array(s0) ** 2 * r
    assert abs(stat.mean() - r) < 4 * np.sqrt(2 * r / 200)
    from scipy import stats
    lo, hi = stats.chi2.ppf([0.025, 0.975], r)
    inside = np.mean((stat > lo) & (stat < hi))
    assert 0.9 < inside <= 1.0


def test_gauss_helmert_weights_both_systems():
    """With equal noise in both systems, sigma0 is ~1 only when both sigmas are given."""
    rng = np.random.default_rng(2)
    src0 = _pts(30, seed=7)
    dst = _proj(src0, "position_vector", True) + rng.normal(0, 0.003, src0.shape)
    src = src0 + rng.normal(0, 0.003, src0.shape)
    one = fit_helmert(src, dst, sigma_target_m=0.003)
    both = fit_helmert(src, dst, sigma_target_m=0.003, sigma_source_m=0.003)
    assert one.sigma0 > 1.2
    assert 0.7 < both.sigma0 < 1.3
    assert np.all(both.translation_sigma_m > one.translation_sigma_m)


def test_blunder_is_flagged_and_clean_points_are_not():
    rng = np.random.default_rng(8)
    src = _pts(15, seed=9)
    dst = _proj(src, "position_vector", True) + rng.normal(0, 0.002, src.shape)
    dst[6, 2] += 10 * 0.002 * 2          # 20 sigma in z
    res = fit_helmert(src, dst, sigma_target_m=0.002, ids=[f"P{i}" for i in range(15)])
    # Every point above the critical value is listed, largest first (issue 21: not
    # only the worst); the blunder leads, its neighbours smeared by it may follow.
    assert res.outliers[0] == "P6" and res.test == "w"
    above = [f"P{i}" for i in np.argsort(-res.w_tests) if res.w_tests[i] > res.critical]
    assert res.outliers == above
    assert res.w_tests[6] > res.critical == pytest.approx(3.29)
    assert np.argmax(res.w_tests) == 6
    assert res.redundancy.sum() == pytest.approx(3 * 15 - 7, rel=1e-9)
    assert np.all(res.mdb_m > 0) and res.global_test["passed"] is False
    res2 = fit_helmert(src, dst, ids=[f"P{i}" for i in range(15)])      # no sigmas: tau
    assert res2.test == "tau" and res2.outliers[0] == "P6"


def test_bad_input_is_reported():
    src = _pts(5)
    with pytest.raises(HelmertError, match="at least 3"):
        fit_helmert(src[:2], src[:2])
    line = UTM + np.outer(np.arange(6.0), [1.0, 2.0, 0.5])
    with pytest.raises(HelmertError, match="non-collinear"):
        fit_helmert(line, line + 1.0)
    with pytest.raises(HelmertError, match="same shape"):
        fit_helmert(src, src[:4])
    with pytest.raises(HelmertError, match="model"):
        fit_helmert(src, src, model="5")
    with pytest.raises(HelmertError, match="sigma_target"):
        fit_helmert(src, src, sigma_target_m=-1.0)


def test_control_point_files(tmp_path):
    a = ControlPoints(["A", "B", "C", "D"], _pts(4), np.full((4, 3), 0.002))
    a.write(tmp_path / "a.csv")
    back = read_control_points(tmp_path / "a.csv")
    assert back.ids == a.ids
    np.testing.assert_allclose(back.xyz, a.xyz, atol=1e-6)
    b = ControlPoints(["C", "A", "X", "B"], _pts(4, seed=2))
    ia, ib = match(a, b)
    assert [a.ids[i] for i in ia] == [b.ids[j] for j in ib] == ["A", "B", "C"]
    with pytest.raises(ControlPointError, match="partner"):
        match(a, b, require_all=True)
    (tmp_path / "dup.csv").write_text("id,x,y,z\nA,1,2,3\nA,4,5,6\n")
    with pytest.raises(ControlPointError, match="unique"):
        read_control_points(tmp_path / "dup.csv")
    (tmp_path / "bad.csv").write_text("id,x,y\nA,1,2\n")
    with pytest.raises(ControlPointError, match="column for h .*--columns"):
        read_control_points(tmp_path / "bad.csv")
    with pytest.raises(ControlPointError, match="at least 3"):
        match(a, ControlPoints(["A", "B"], _pts(2)))


def test_transform_applies_to_trajectories():
    from sensors import Trajectory
    src = _pts(6, seed=12)
    h = from_parameters([1.0, 2.0, 3.0], [0.0, 0.0, 3600.0 * 90], 0.0)
    tr = Trajectory(np.arange(6.0), src, Rotation.identity(6))
    out = h.apply_trajectory(tr)
    np.testing.assert_allclose(out.positions, h.apply(src), atol=1e-9)
    np.testing.assert_allclose(out.rotations.as_matrix(), np.tile(h.rotation_matrix, (6, 1, 1)),
                               atol=1e-12)


def test_package_exports_the_documented_api():
    import survey
    assert survey.fit_helmert is fit_helmert
    res = survey.fit_helmert(_pts(5), _pts(5) + 1.0, model="6")
    np.testing.assert_allclose(res.translation_m, [1.0, 1.0, 1.0], atol=1e-8)
    assert res.w_tests.shape == (5,) and res.residuals.shape == (5, 3)


def test_textbook_example_with_errors_in_both_systems():
    """The 3-D conformal example of Wolf & Ghilani, "Adjustment Computations" (4 points,
    standard deviations in both systems). Reference: the scale of an independent
    rigorous errors-in-both-systems solution of the same data published in a public
    repository (example3DConformal.m, total least squares): 0.9499549354, 10 digits.
    Our Gauss-Helmert solution reproduces all of them; target-only weighting does not
    (it differs in the 7th digit), so the test tells the two models apart."""
    x = np.array([[1094.883, 820.085, 109.821], [503.891, 1598.698, 117.685],
                  [2349.343, 207.658, 151.387], [1395.320, 1348.853, 215.261]])
    xt = np.array([[10037.810, 5262.090, 772.040], [10956.680, 5128.170, 783.000],
                   [8780.080, 4840.290, 782.620], [10185.800, 4700.210, 851.320]])
    s_src = np.array([[7, 8, 5], [11, 8, 9], [6, 5, 7], [5, 8, 9]]) * 0.001
    s_tgt = np.array([[5, 6, 5], [4, 6, 9], [2, 4, 2], [3, 5, 3]]) * 0.01
    # A real scale of 0.95 (-50,000 ppm, a local system): beyond the unit guard, so
    # it is allowed explicitly (issue 21).
    with pytest.raises(HelmertError, match="same unit"):
        fit_helmert(x, xt, sigma_source_m=s_src, sigma_target_m=s_tgt)
    gh = fit_helmert(x, xt, sigma_source_m=s_src, sigma_target_m=s_tgt, allow_scale=True)
    assert 1 + gh.scale_ppm * 1e-6 == pytest.approx(0.9499549354, abs=5e-11)
    target_only = fit_helmert(x, xt, sigma_target_m=s_tgt, allow_scale=True)
    assert abs(1 + target_only.scale_ppm * 1e-6 - 0.9499549354) > 1e-7
