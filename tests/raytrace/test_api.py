"""The Scene API as a NumPy user meets it: keyword-only, validated limits; (3,) and
(n, 3) rows alike; the mesh readable back; incidence angles; short reprs; package
errors (never a bare ValueError) for bad settings."""

from __future__ import annotations

import inspect
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import raytrace
from raytrace import ConfigError, Hits, MeshError, RayError, Scene, SceneFileError
from raytrace.scene import FILE_FORMAT
from raytrace.shapes import icosphere

ROOT = Path(__file__).resolve().parents[2]

# Two parallel unit triangles at z = 1 and z = 2 over the unit square's lower half.
TWO_PLANES_V = np.array([[0, 0, 1], [1, 0, 1], [0, 1, 1], [0, 0, 2], [1, 0, 2], [0, 1, 2.0]])
TWO_PLANES_F = np.array([[0, 1, 2], [3, 4, 5]])


@pytest.fixture(scope="module")
def planes():
    return Scene(TWO_PLANES_V, TWO_PLANES_F)


@pytest.fixture(scope="module")
def sphere():
    v, f = icosphere(3, radius=2.0)
    return Scene(v, f), v, f


# ---------------------------------------------------------------------- limits
def test_limits_are_keyword_only_with_one_vocabulary():
    cast = inspect.signature(Scene.cast).parameters
    occ = inspect.signature(Scene.occluded).parameters
    assert list(cast)[:5] == list(occ)[:5] == ["self", "origins", "directions", "t_min",
                                                "t_max"]
    for params in (cast, occ):
        for name in ("t_min", "t_max"):
            assert params[name].kind is inspect.Parameter.KEYWORD_ONLY
    assert cast["method"].kind is inspect.Parameter.KEYWORD_ONLY
    assert cast["t_min"].default == occ["t_min"].default == 0.0
    assert cast["t_max"].default == occ["t_max"].default == np.inf


def test_positional_limits_are_refused_not_swapped(planes):
    """The old trap: occluded(o, d, 0.0, 10.0) answered for t_max = 0 (all False)."""
    o, d = [0.1, 0.1, 0.0], [[0, 0, 1.0]]
    with pytest.raises(TypeError, match="positional"):
        planes.occluded(o, d, 0.0, 10.0)
    with pytest.raises(TypeError, match="positional"):
        planes.cast(o, d, 0.0, 10.0)
    assert planes.occluded(o, d, t_min=0.0, t_max=10.0).tolist() == [True]
    assert planes.cast(o, d, t_min=0.0, t_max=10.0).t.tolist() == [1.0]


@pytest.mark.parametrize("limits, match", [
    (dict(t_min=2.0, t_max=1.0), r"`t_min` <= `t_max` .*got t_min 2.0 > t_max 1.0; pass "
                                 r"the limits by keyword"),
    (dict(t_min=np.array([0.0, 3.0]), t_max=np.array([1.0, 2.0])),
     r"got t_min 3.0 > t_max 2.0 at ray\(s\) 1;"),
    (dict(t_max=-np.inf), r"`t_min` <= `t_max`"),
    (dict(t_min=-0.5), r"finite `t_min` >= 0, got -0.5; rays start at their origin"),
    (dict(t_min=np.inf), r"finite `t_min` >= 0, got inf"),
    (dict(t_min=np.array([0.0, -1.0])), r"`t_min` >= 0, got -1.0 at ray\(s\) 1;"),
    (dict(t_max=np.nan), r"`t_max` without NaN, got NaN; use inf for no limit"),
    (dict(t_max=np.array([1.0, np.nan])), r"`t_max` without NaN, got NaN at ray\(s\) 1;"),
    (dict(t_max=np.ones(3)), r"`t_max` to be a scalar or shape \(2,\) .*got \(3,\)"),
    (dict(t_min=np.zeros((2, 1))), r"`t_min` to be a scalar or shape \(2,\) .*got \(2, 1\)"),
    (dict(t_max="far"), r"`t_max` to be a number or an array of numbers, got str"),
])
@pytest.mark.parametrize("query", ["cast", "occluded"])
def test_bad_limits_are_named(planes, query, limits, match):
    rays = ([0.1, 0.1, 0.0], [[0, 0, 1.0], [0, 0, 1.0]])
    with pytest.raises(RayError, match=match):
        getattr(planes, query)(*rays, **limits)


def test_limits_per_ray_and_shared_agree(planes):
    d = np.array([[0, 0, 1.0]] * 4)
    o = [0.1, 0.1, 0.0]
    for lo, hi, want_tri in [(0.0, np.inf, 0), (1.5, np.inf, 1), (1.0, 1.0, 0),
                             (2.0, 2.0, 1), (1.1, 1.9, -1)]:
        shared = planes.cast(o, d, t_min=lo, t_max=hi)
        per_ray = planes.cast(o, d, t_min=np.full(4, lo), t_max=np.full(4, hi))
        assert shared.triangle.tolist() == per_ray.triangle.tolist() == [want_tri] * 4
        assert planes.occluded(o, d, t_min=lo, t_max=hi).tolist() == [want_tri >= 0] * 4


def test_rows_of_three_and_n_by_three_alike(sphere):
    scene = sphere[0]
    rng = np.random.default_rng(4)
    d = rng.standard_normal((500, 3))
    o = np.array([0.3, -0.2, 0.1])
    one = scene.cast(o, d)
    many = scene.cast(np.tile(o, (500, 1)), d)
    np.testing.assert_array_equal(one.t, many.t)
    np.testing.assert_array_equal(one.triangle, many.triangle)
    np.testing.assert_array_equal(scene.occluded(o, d, t_max=1.9),
                                  scene.occluded(np.tile(o, (500, 1)), d, t_max=1.9))
    # One direction shared by many origins: the origins move, the direction does not.
    origins = rng.uniform(-1, 1, (300, 3))
    shared = scene.cast(origins, [0, 0, 1.0])
    ref = scene.cast(origins, np.tile([0, 0, 1.0], (300, 1)))
    np.testing.assert_array_equal(shared.t, ref.t)
    np.testing.assert_array_equal(scene.occluded(origins, [0, 0, 1.0], t_max=0.5),
                                  ref.t <= 0.5)
    # A single ray from rows of three: one result, not a broadcasting surprise.
    assert len(scene.cast(o, [0, 0, 1.0])) == 1


@pytest.mark.parametrize("origins, directions, match", [
    (np.zeros((3, 3)), np.ones((2, 3)), r"`origins` to have shape \(2, 3\) or \(3,\), "
                                        r"got \(3, 3\)"),
    (np.zeros(3), np.ones(2), r"`directions` to have shape \(n, 3\), got \(2,\)"),
    ("here", np.ones((2, 3)), r"`origins` as numbers, got str"),
    (np.zeros(3), [[0, 0, "up"]], r"`directions` as numbers"),
    (np.zeros(3), np.zeros(3), r"zero length at row\(s\) 0"),
])
def test_bad_rays_are_named(planes, origins, directions, match):
    for query in (planes.cast, planes.occluded):
        with pytest.raises(RayError, match=match):
            query(origins, directions)


def test_structured_xyz_arrays_are_points():
    dtype = np.dtype([("x", "f8"), ("y", "f8"), ("z", "f8"), ("label", "u1")])
    v = np.zeros(6, dtype=dtype)
    for name, col in zip("xyz", TWO_PLANES_V.T, strict=True):
        v[name] = col
    scene = Scene(v, TWO_PLANES_F)
    np.testing.assert_array_equal(scene.vertices, TWO_PLANES_V)
    origin = np.zeros(1, dtype=dtype)
    origin["x"], origin["y"] = 0.1, 0.1
    assert scene.cast(origin, [0, 0, 1.0]).t.tolist() == [1.0]
    with pytest.raises(MeshError, match="fields x, y, z, got fields a, b"):
        Scene(np.zeros(3, dtype=[("a", "f8"), ("b", "f8")]), [[0, 1, 2]])


# ---------------------------------------------------------------------- the mesh
def test_vertices_and_faces_are_what_was_given(tmp_path):
    v, f = icosphere(2)
    f[5] = [3, 3, 4]  # one zero-area face: dropped from the BVH, kept in `faces`
    with pytest.warns(UserWarning, match="Dropped 1 zero-area"):
        scene = Scene(v + 1000.0, f.astype(np.int32))
    assert scene.vertices.dtype == np.float64 and scene.faces.dtype == np.int64
    np.testing.assert_array_equal(scene.vertices, v + 1000.0)
    np.testing.assert_array_equal(scene.faces, f)
    assert scene.n_triangles == len(f) - 1
    with pytest.raises(ValueError, match="read-only"):
        scene.vertices[0, 0] = 0.0
    with pytest.raises(ValueError, match="read-only"):
        scene.faces[0, 0] = 1
    # Hits.triangle indexes the faces given: the hit point lies in that face's plane.
    h = scene.cast([1000.0, 1000.0, 1000.0], np.random.default_rng(0).normal(size=(200, 3)))
    p = scene.vertices[scene.faces[h.triangle]]
    nrm = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    off_plane = np.einsum("ij,ij->i", h.points - p[:, 0], nrm) / np.linalg.norm(nrm, axis=1)
    assert h.hit.all() and np.abs(off_plane).max() < 1e-9
    again = Scene.load(scene.save(tmp_path / "s.npz"))
    np.testing.assert_array_equal(again.vertices, scene.vertices)
    np.testing.assert_array_equal(again.faces, scene.faces)
    assert again.n_triangles == scene.n_triangles


def test_copy_data_decides_whether_the_callers_arrays_are_kept():
    v, f = icosphere(1)
    shared = Scene(v, f)
    copied = Scene(v, f, copy_data=True)
    assert np.shares_memory(shared.vertices, v) and np.shares_memory(shared.faces, f)
    assert not np.shares_memory(copied.vertices, v)
    assert not np.shares_memory(copied.faces, f)
    assert v.flags.writeable  # the caller's own array is left as it was


def test_old_scene_files_are_refused(tmp_path):
    scene = Scene(TWO_PLANES_V, TWO_PLANES_F)
    path = scene.save(tmp_path / "s.npz")
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files if k not in ("vertices", "faces")}
    # The previous format (5: 4-wide node records) must not be read as the current one.
    new, old = FILE_FORMAT, FILE_FORMAT - 1
    info = bytes(arrays["info"]).replace(f'"format": {new}'.encode(), f'"format": {old}'.encode())
    arrays["info"] = np.frombuffer(info, dtype=np.uint8)
    np.savez(tmp_path / "old.npz", **arrays)
    with pytest.raises(SceneFileError,
                       match=f"format {new}, got {old} .*rebuild it from the mesh"):
        Scene.load(tmp_path / "old.npz")


# ---------------------------------------------------------------------- incidence
def test_incidence_on_a_plane_is_the_analytic_angle():
    """Rays at a known angle theta from the z axis meet the z = 1 plane at incidence
    theta, from either side (the angle is to the normal line, not its sign)."""
    big = Scene(TWO_PLANES_V * [2e4, 2e4, 1] - [1e4, 1e4, 0], TWO_PLANES_F)  # 20 km
    theta = np.array([0.0, 0.1, 0.5, 1.0, 1.4, np.pi / 2 - 1e-3])
    # Towards -x: the triangles' hypotenuse runs through (0, 0).
    up = np.stack([-np.sin(theta), np.zeros_like(theta), np.cos(theta)], axis=1)
    below = big.cast([0.0, 0.0, 0.5], up)
    assert (below.triangle == 0).all()
    np.testing.assert_allclose(below.incidence_rad, theta, rtol=0, atol=1e-12)
    assert below.incidence_rad[0] == 0.0
    # From above the upper plane, looking down at its front: the same angles.
    down = up * np.array([1, 1, -1])
    above = big.cast([0.0, 0.0, 2.5], down)
    assert (above.triangle == 1).all()
    np.testing.assert_allclose(above.incidence_rad, theta, rtol=0, atol=1e-12)


def test_incidence_matches_an_independent_computation(sphere):
    scene, v, f = sphere
    rng = np.random.default_rng(21)
    o = rng.uniform(-1, 1, (3000, 3))
    d = rng.standard_normal((3000, 3)) * rng.uniform(0.1, 10, (3000, 1))  # not unit
    o[:500] = [5.0, 0, 0]  # some from outside, many of them missing
    h = scene.cast(o, d)
    assert h.hit.any() and not h.hit.all()
    m = h.hit
    p = v[f[h.triangle[m]]]
    nrm = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    cos = np.abs(np.einsum("ij,ij->i", d[m], nrm)) / (
        np.linalg.norm(d[m], axis=1) * np.linalg.norm(nrm, axis=1))
    ref = np.arccos(np.clip(cos, 0.0, 1.0))
    # arccos loses digits near 0 (~sqrt(2 eps) ~ 2e-8 rad); far below any use.
    np.testing.assert_allclose(h.incidence_rad[m], ref, rtol=0, atol=1e-7)
    assert np.isnan(h.incidence_rad[~m]).all()
    assert (h.incidence_rad[m] >= 0).all() and (h.incidence_rad[m] <= np.pi / 2).all()
    # Rays from the centre of a sphere meet it almost square on.
    centre = scene.cast(np.zeros(3), rng.standard_normal((1000, 3)))
    assert centre.incidence_rad.max() < 0.1


# ---------------------------------------------------------------------- reprs
def test_reprs_are_one_short_line(planes, sphere):
    text = repr(sphere[0])
    assert text.startswith("Scene(1,280 triangles, BVH ") and " MB, bounds (" in text
    assert "\n" not in text and len(text) < 120
    assert repr(planes) == "Scene(2 triangles, BVH 0.0 MB, bounds (0, 0, 1) .. (1, 1, 2) m)"
    h = planes.cast([0.1, 0.1, 0.0], [[0, 0, 1.0], [0, 0, -1.0], [0, 0, 1.0]])
    assert isinstance(h, Hits) and repr(h) == "Hits(3 rays, 2 hit)"
    assert repr(planes.cast(np.zeros(3), np.zeros((0, 3)))) == "Hits(0 rays, 0 hit)"


def test_empty_batches_keep_their_dtypes(planes):
    h = planes.cast(np.zeros(3), np.zeros((0, 3)))
    assert h.incidence_rad.shape == (0,) and h.normals.shape == (0, 3)
    assert h.points.shape == (0, 3) and h.triangle.dtype == np.int64
    occ = planes.occluded(np.zeros(3), np.zeros((0, 3)), t_max=np.zeros(0))
    assert occ.shape == (0,) and occ.dtype == np.bool_


# ---------------------------------------------------------------------- settings
def test_settings_raise_config_errors():
    before = raytrace.threads()
    try:
        for bad in (0, raytrace.max_threads() + 1):
            with pytest.raises(ConfigError, match=r"Expected a thread count between 1 and "
                                                  rf"{raytrace.max_threads()}, got {bad}; "):
                raytrace.set_threads(bad)
        with pytest.raises(ConfigError, match="whole-number thread count, got 2.5"):
            raytrace.set_threads(2.5)
        assert raytrace.set_threads(None) == raytrace.max_threads()
    finally:
        raytrace.set_threads(before)
    with pytest.raises(ConfigError, match=r"2 <= sah_bins <= 256.*got sah_bins=1,"):
        Scene(TWO_PLANES_V, TWO_PLANES_F, sah_bins=1)
    with pytest.raises(ConfigError, match=r"c_trav=nan"):
        Scene(TWO_PLANES_V, TWO_PLANES_F, c_trav=float("nan"))
    with pytest.raises(ConfigError, match=r"max_leaf_size=2.5"):
        Scene(TWO_PLANES_V, TWO_PLANES_F, max_leaf_size=2.5)
    assert issubclass(ConfigError, ValueError)
    assert issubclass(ConfigError, raytrace.TunnelsimError)


def test_threads_environment_variable_is_checked():
    code = "import raytrace; print(raytrace.threads())"
    env = dict(os.environ, TUNNELSIM_THREADS="1")
    ok = subprocess.run([sys.executable, "-c", code], env=env, cwd=ROOT,
                        capture_output=True, text=True)
    assert ok.returncode == 0 and ok.stdout.strip() == "1", ok.stderr
    env["TUNNELSIM_THREADS"] = "many"
    bad = subprocess.run([sys.executable, "-c", code], env=env, cwd=ROOT,
                         capture_output=True, text=True)
    assert bad.returncode != 0
    assert "ConfigError: Expected the environment variable TUNNELSIM_THREADS to be a " \
           "thread count" in bad.stderr and "got 'many'; fix or unset it." in bad.stderr


def test_every_public_raytrace_module_declares_all():
    import importlib

    for name in ("raytrace", "raytrace.scene", "raytrace.hits", "raytrace.config",
                 "raytrace.errors", "raytrace.shapes", "raytrace.fileio", "raytrace.lazy"):
        mod = importlib.import_module(name)
        assert mod.__all__ and all(hasattr(mod, n) for n in mod.__all__), name
