"""The survey library as a NumPy user meets it: one argument vocabulary, validation at
the call, (3,) and (n, 3) alike, structured point arrays accepted, short reprs.

Every acceptance test compares against the same call on the plain (n, 3) float64 array,
which the rest of the suite checks against brute force, PROJ and Open3D."""

from __future__ import annotations

import inspect

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from survey.adjust.drift import fit_drift
from survey.adjust.helmert import HelmertResult, fit_helmert, from_parameters, model_name
from survey.analysis.compare import (
    Distances,
    ReferenceCloud,
    ReferenceMesh,
    cloud_to_cloud,
    cloud_to_mesh,
)
from survey.analysis.planning import Plan, Thresholds
from survey.clouds.preprocess import (
    VoxelGrid,
    radius_outliers,
    statistical_outliers,
    voxel_down_sample,
)
from survey.errors import (
    AlignmentError,
    CompareError,
    DriftError,
    HelmertError,
    PreprocessError,
)
from survey.report.adjustment import helmert_report
from survey.world.alignment import Alignment, arc, straight
from survey.world.generator import make_tunnel
from survey.world.profiles import horseshoe

UTM = np.array([451_000.0, 5_352_000.0, 600.0])
RECORD = np.dtype([("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("intensity", "<u2")])
#: A PLY vertex element as trimesh and Open3D write it: float32 coordinates.
VERTEX32 = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4")])

coords = arrays(np.float64, st.tuples(st.integers(1, 40), st.just(3)),
                elements=st.floats(-5.0, 5.0, allow_nan=False, width=64))


def _records(p, dtype=RECORD):
    rec = np.zeros(len(p), dtype=dtype)
    rec["x"], rec["y"], rec["z"] = p.T
    return rec


def _plain(rec):
    return np.stack([rec["x"], rec["y"], rec["z"]], 1).astype(np.float64)


def _mesh():
    """A closed octahedron around the origin and a floor triangle below it."""
    v = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1],
                  [-6, -6, -3], [6, -6, -3], [0, 6, -3]])
    f = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5],
                  [3, 1, 5], [0, 3, 5], [6, 7, 8]])
    return v, f


def _pts(n=8, seed=0):
    return np.random.default_rng(seed).uniform(-80, 80, (n, 3)) * [1, 1, 0.2] + UTM


# ------------------------------------------------------------------- Helmert model
@pytest.mark.parametrize("model", [7, "7", np.int64(7), " 7"])
def test_fit_helmert_takes_the_model_as_int_or_string(model):
    src = _pts()
    dst = from_parameters([1.0, -2.0, 0.5], [3.0, -1.0, 20.0], 12.0).apply(src)
    want = fit_helmert(src, dst, model="7").to_dict()
    got = fit_helmert(src, dst, model=model)
    assert got.model == "7"                      # the JSON keeps writing "7"
    assert got.to_dict() == want


@pytest.mark.parametrize("model, u", [(6, 6), ("6", 6), (9, 9), ("9", 9)])
def test_models_6_and_9_as_int(model, u):
    src = _pts(10, seed=3)
    dst = src + [0.5, 0.2, -0.1]
    res = fit_helmert(src, dst, model=model)
    assert res.model == str(u) and res.correlation.shape == (u, u)
    np.testing.assert_allclose(res.apply(src), dst, atol=1e-8)


@pytest.mark.parametrize("bad", [5, "5", 7.0, True, None, "seven", [7]])
def test_a_bad_model_names_the_choices(bad):
    with pytest.raises(HelmertError, match=r"Expected model 7, 6 or 9"):
        fit_helmert(_pts(), _pts(), model=bad)
    with pytest.raises(HelmertError, match="Expected model"):
        model_name(bad)


def test_fit_helmert_keyword_only_and_unit_names():
    src = _pts()
    # Positional model or sigmas are refused: sigma_source_m and sigma_target_m would be
    # easy to swap.
    with pytest.raises(TypeError):
        fit_helmert(src, src + 1.0, 7)
    params = inspect.signature(fit_helmert).parameters
    assert {"sigma_source_m", "sigma_target_m"} <= set(params)
    assert all(params[k].kind is inspect.Parameter.KEYWORD_ONLY
               for k in ("model", "sigma_source_m", "sigma_target_m", "ids"))
    with pytest.raises(HelmertError, match="sigma_source_m"):
        fit_helmert(src, src + 1.0, sigma_source_m=[1.0, 2.0])
    with pytest.raises(HelmertError, match="one id per point"):
        fit_helmert(src, src + 1.0, ids=["a", "b"])
    with pytest.raises(HelmertError, match="max_iter"):
        fit_helmert(src, src + 1.0, max_iter=0)


# ------------------------------------------------------- structured arrays accepted
@settings(max_examples=25, deadline=None)
@given(coords)
def test_cloud_to_mesh_structured_equals_plain(p):
    v, f = _mesh()
    plain = cloud_to_mesh(p, v, f)
    rec = cloud_to_mesh(_records(p), v, f)
    np.testing.assert_array_equal(rec.distance, plain.distance)
    np.testing.assert_array_equal(rec.nearest, plain.nearest)
    # float32 vertex records (a PLY) give what their float64 values give.
    r32 = _records(p, VERTEX32)
    np.testing.assert_array_equal(cloud_to_mesh(r32, v, f).distance,
                                  cloud_to_mesh(_plain(r32), v, f).distance)
    # A structured reference mesh too.
    np.testing.assert_array_equal(cloud_to_mesh(p, _records(v), f).distance,
                                  plain.distance)


@settings(max_examples=25, deadline=None)
@given(coords, coords)
def test_cloud_to_cloud_structured_equals_plain(p, q):
    plain = cloud_to_cloud(p, q, split=True, max_distance_m=2.0)
    rec = cloud_to_cloud(_records(p), _records(q), split=True, max_distance_m=2.0)
    for name in ("distance", "nearest", "dx", "dy", "dz"):
        np.testing.assert_array_equal(getattr(rec, name), getattr(plain, name))


@settings(max_examples=20, deadline=None)
@given(arrays(np.float64, (6, 3), elements=st.floats(-100, 100, width=64)))
def test_helmert_structured_equals_plain(noise):
    src = _pts(6, seed=1)
    dst = from_parameters([1.0, 2.0, 3.0], [10.0, -5.0, 30.0], 4.0).apply(src) + \
        noise * 1e-5
    plain = fit_helmert(src, dst)
    rec = fit_helmert(_records(src), _records(dst))
    assert rec.to_dict() == plain.to_dict()
    np.testing.assert_array_equal(plain.apply(_records(src)), plain.apply(src))


def test_preprocess_takes_structured_arrays():
    p = np.random.default_rng(2).uniform(0, 3, (500, 3))
    rec = _records(p)
    np.testing.assert_array_equal(voxel_down_sample(rec, 0.5), voxel_down_sample(p, 0.5))
    np.testing.assert_array_equal(statistical_outliers(rec, k=6),
                                  statistical_outliers(p, k=6))
    np.testing.assert_array_equal(radius_outliers(rec, min_neighbours=2, radius_m=0.2),
                                  radius_outliers(p, min_neighbours=2, radius_m=0.2))
    g1, g2 = VoxelGrid(0.5, p.min(axis=0)), VoxelGrid(0.5, p.min(axis=0))
    g1.add(rec)
    g2.add(p)
    np.testing.assert_array_equal(g1.result()[0], g2.result()[0])


def test_alignment_takes_structured_and_single_points():
    al = Alignment([straight(20.0), arc(15.0, 40.0)], start_xy=UTM[:2],
                   profile=((0.0, UTM[2]),))
    p = al.to_world(np.array([3.0, 25.0, 31.0]), [0.5, -1.0, 0.2], [1.0, 2.0, 0.3])
    want = al.to_local(p)
    got = al.to_local(_records(p))
    for a, b in zip(got, want):
        np.testing.assert_array_equal(a, b)
    one = al.to_local(p[1])                       # a (3,) point measures as n = 1
    for a, b in zip(one, want):
        assert a.shape == (1,)
        # Newton stops when every point of a batch has converged: 1e-11 m apart.
        np.testing.assert_allclose(a[0], b[1], rtol=0, atol=1e-9)


def test_a_structured_array_without_z_is_refused_by_name():
    rec = np.zeros(3, dtype=[("x", "f8"), ("y", "f8"), ("intensity", "u2")])
    with pytest.raises(CompareError, match="fields x, y, z.*x, y, intensity"):
        cloud_to_cloud(rec, np.zeros((3, 3)))
    with pytest.raises(HelmertError, match="fields x, y, z"):
        fit_helmert(rec, rec)
    with pytest.raises(PreprocessError, match="fields x, y, z"):
        voxel_down_sample(rec, 0.1)


@pytest.mark.parametrize("bad", [[["a", "b", "c"]], "points", {"x": 1}, object()])
def test_non_numeric_points_raise_the_package_error_not_typeerror(bad):
    with pytest.raises(CompareError, match="Expected `compared` as numbers"):
        cloud_to_cloud(bad, np.zeros((3, 3)))
    with pytest.raises(HelmertError, match="Expected `source` as numbers"):
        fit_helmert(bad, _pts())
    with pytest.raises(AlignmentError, match="Expected `points` as numbers"):
        Alignment([straight(10.0)]).to_local(bad)


# ------------------------------------------------------------ one (3,) point alike
@settings(max_examples=40, deadline=None)
@given(arrays(np.float64, 3, elements=st.floats(-1e3, 1e3, width=64)))
def test_helmert_apply_one_point_is_row_0_of_the_1x3_call(p):
    for h in (from_parameters([1.0, -2.0, 3.0], [5.0, 6.0, -7.0], 9.0),
              HelmertResult.from_dict({"model": 9, "translation_m": [0, 0, 1],
                                       "rotation_arcsec": [0, 0, 90],
                                       "scale_ppm": [1.0, 2.0, 3.0]})):
        one = h.apply(p)
        assert one.shape == (3,)
        np.testing.assert_array_equal(one, h.apply(p[None])[0])
        np.testing.assert_array_equal(h.apply(p, exact=False),
                                      h.apply(p[None], exact=False)[0])


@settings(max_examples=40, deadline=None)
@given(arrays(np.float64, 3, elements=st.floats(-8, 8, width=64)))
def test_cloud_to_mesh_and_cloud_one_point_measure_as_n_1(p):
    v, f = _mesh()
    one = cloud_to_mesh(p, v, f, max_distance_m=3.0)
    row = cloud_to_mesh(p[None], v, f, max_distance_m=3.0)
    assert one.distance.shape == one.nearest.shape == (1,)
    np.testing.assert_array_equal(one.distance, row.distance)
    np.testing.assert_array_equal(one.nearest, row.nearest)
    c = cloud_to_cloud(p, v, split=True)
    assert c.distance.shape == c.dx.shape == (1,)
    np.testing.assert_array_equal(c.distance, cloud_to_cloud(p[None], v).distance)
    # The distance is the plain Euclidean one to the nearest vertex.
    assert c.distance[0] == pytest.approx(np.linalg.norm(v - p, axis=1).min(), abs=1e-12)


def test_drift_correction_applies_to_one_point():
    rng = np.random.default_rng(5)
    g = rng.uniform(-20, 20, (9, 3)) + UTM
    t = np.repeat([0.0, 10.0, 20.0], 3)
    m = g + rng.normal(0, 0.01, g.shape) + np.outer(t, [0.01, 0.0, 0.0])
    corr = fit_drift(m, t, g, sigma_world_m=0.002)
    many = corr.apply(m, t)
    one = corr.apply(m[4], t[4])
    assert one.shape == (3,)
    np.testing.assert_allclose(one, many[4], rtol=0, atol=1e-9)
    np.testing.assert_array_equal(corr.apply(_records(m), t), many)
    with pytest.raises(DriftError, match="one time per point"):
        corr.apply(m, t[:3])


# ------------------------------------------------------------------ validations
@pytest.mark.parametrize("bad", [0, -1.0, float("nan"), "far"])
def test_max_distance_m_is_validated(bad):
    with pytest.raises(CompareError, match="max_distance_m"):
        cloud_to_cloud(np.zeros((2, 3)), np.ones((3, 3)), max_distance_m=bad)
    v, f = _mesh()
    with pytest.raises(CompareError, match="max_distance_m"):
        cloud_to_mesh(np.zeros((2, 3)), v, f, max_distance_m=bad)


def test_units_in_names_and_keyword_only_filters():
    for fn, names in ((cloud_to_cloud, {"max_distance_m"}), (cloud_to_mesh, {"max_distance_m"}),
                      (voxel_down_sample, {"voxel_size_m"}),
                      (radius_outliers, {"radius_m", "min_neighbours"}),
                      (fit_drift, {"sigma_world_m"})):
        assert names <= set(inspect.signature(fn).parameters), fn.__name__
    assert list(inspect.signature(cloud_to_mesh).parameters)[:3] == \
        ["compared", "vertices", "faces"]
    p = np.zeros((5, 3))
    with pytest.raises(TypeError):
        radius_outliers(p, 4, 0.05)
    with pytest.raises(TypeError):
        statistical_outliers(p, 8, 2.0)


def test_voxel_grid_checks_its_bound_and_size():
    with pytest.raises(PreprocessError, match="min_bound"):
        VoxelGrid(0.1, [0.0, 0.0])
    with pytest.raises(PreprocessError, match="min_bound"):
        VoxelGrid(0.1, [0.0, np.nan, 0.0])
    with pytest.raises(PreprocessError, match="positive voxel size"):
        VoxelGrid("big", [0.0, 0.0, 0.0])
    assert VoxelGrid(0.25, [0.0, 0.0, 0.0]).voxel_size_m == 0.25


def test_nan_points_are_named_with_their_row():
    p = np.zeros((4, 3))
    p[2, 1] = np.nan
    with pytest.raises(CompareError, match="row 2"):
        ReferenceCloud(np.ones((3, 3))).distances(p)
    with pytest.raises(PreprocessError, match="finite"):
        statistical_outliers(p)


def test_reference_mesh_names_what_is_wrong_with_faces():
    v, f = _mesh()
    # Float faces are a dtype problem, not a shape one: the message must say so.
    for bad in (f + 0.5, np.asarray(f, dtype=np.float32) - 0.25):
        with pytest.raises(CompareError, match=r"integer `faces`.*non-integer values") as e:
            ReferenceMesh(v, bad)
        assert "shape" not in str(e.value)
    with pytest.raises(CompareError, match=r"integer `faces`.*got dtype float64;"):
        cloud_to_mesh(np.zeros((2, 3)), v, f.astype(np.float64))
    with pytest.raises(CompareError, match=r"below 9, got indices from 0 to 9\."):
        ReferenceMesh(v, np.where(f == 8, 9, f))
    with pytest.raises(CompareError, match=r"got shape \(9, 2\)"):
        ReferenceMesh(v, f[:, :2])
    assert len(ReferenceMesh(v, f).tris) == len(f)


# ------------------------------------------------------------------------ reprs
@pytest.fixture(scope="module")
def tunnel():
    return make_tunnel(Alignment([straight(30.0)]), horseshoe(5.6), edge_length_m=0.5,
                       roughness_rms_m=0.0, name="demo")


def test_tunnel_mesh_prints_one_line(tunnel):
    text = repr(tunnel)
    assert "\n" not in text and len(text) < 160, text
    assert text.startswith("TunnelMesh(demo: ")
    assert f"{len(tunnel.faces):,} triangles" in text and "30.0 m" in text
    assert tunnel.profile.name in text
    assert f"{len(np.unique(tunnel.labels))} labels" in text


def test_alignment_profile_distances_plan_print_short(tunnel):
    for obj, start in ((tunnel.alignment, "Alignment(30.0 m"),
                       (tunnel.profile, "Profile('horseshoe"),
                       (cloud_to_cloud(np.zeros((3, 3)), np.ones((2, 3))),
                        "Distances(3 points"),
                       (Plan("every 10 m", np.zeros((2, 3)), np.array([5.0, 15.0]),
                             np.zeros(4, int), np.zeros(4, int), 0.875, np.zeros(2),
                             np.zeros(1)), "Plan('every 10 m', 2 stations, coverage 87.50 %"),
                       (Thresholds(), "Thresholds(spacing_m=0.005, incidence_rad=1.2217 "
                                      "(70.0 deg)")):
        text = repr(obj)
        assert text.startswith(start) and "\n" not in text and len(text) < 160, text
        assert " at 0x" not in text


def test_distances_repr_states_mean_in_mm():
    d = Distances(np.array([0.001, -0.003]), np.array([0, -1]))
    assert repr(d) == ("Distances(2 points, mean -1.00 mm, RMS 2.24 mm, max |d| 3.00 mm, "
                       "1 clamped)")


def test_helmert_prints_two_lines_and_reports_in_full():
    src = _pts(12, seed=4)
    dst = from_parameters([1.0, 2.0, 3.0], [10.0, -5.0, 30.0], 4.0).apply(src)
    dst += np.random.default_rng(4).normal(0, 0.002, dst.shape)
    dst[2] += 0.05
    res = fit_helmert(src, dst, sigma_target_m=0.002, ids=[f"P{i}" for i in range(12)])
    text = repr(res)
    assert text.count("\n") <= 1 and len(text) < 240, text
    assert "model 7" in text and "12 points" in text and "w-test outliers: P2" in text
    full = helmert_report(res)              # the long form
    assert all(f"| P{i}" in full for i in range(12)) and full.count("\n") > 20
    assert repr(from_parameters([0, 0, 0], [0, 0, 0])).endswith("from parameters)")
