"""Tunnel-aware reconstruction on a generated tunnel with known truth."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from raytrace import Scene
from sensors import Trajectory, load_sensor, simulate_drive
from sensors.spec import SPEC_DIR
from survey.world.alignment import Alignment, curve, straight
from survey.clouds.preprocess import voxel_down_sample
from survey.world.profiles import horseshoe
from survey.errors import ReconstructionError
from survey.clouds.reconstruct import reconstruct_tunnel
from survey.world.generator import make_tunnel


@pytest.fixture(scope="module")
def scanned(tmp_path_factory):
    """A 45 m curved horseshoe tunnel (2 mm roughness) scanned by a profile scanner on
    a trolley (device noise on), voxelised at 2 cm."""
    al = Alignment([straight(20.0), *curve(0.2, 150.0, 5.0), straight(15.0)])
    tun = make_tunnel(al, horseshoe(2.8), edge_length_m=0.05, roughness_rms_m=0.002, seed=1)
    scene = Scene(tun.vertices, tun.faces)
    c0, c1 = al.chainage_range
    s = np.arange(c0 + 0.5, c1 - 0.5, 0.25)
    traj = Trajectory.along_polyline(al.to_world(s, 0.0, 1.2), 1.0, rate_hz=50)
    text = (SPEC_DIR / "zf_profiler_9012.toml").read_text()
    text = text.replace("profile_rate_hz = 200.0", "profile_rate_hz = 30.0")
    text = text.replace("points_per_profile = 5000", "points_per_profile = 700")
    text = text.replace('name = "zf_profiler_9012"', 'name = "test_profiler"')
    toml = tmp_path_factory.mktemp("spec") / "p.toml"
    toml.write_text(text)
    pts = np.concatenate(list(simulate_drive(scene, load_sensor(toml), traj,
                                             reflectivity=0.4, seed=2)))
    cloud = voxel_down_sample(np.stack([pts["x"], pts["y"], pts["z"]], 1), 0.02)
    return al, scene, cloud


def _radial_error(rec, scene):
    """Distance of each reconstructed vertex to the true mesh along the ray from the
    axis through it (our engine casts against the true tunnel)."""
    s, o, h = rec.alignment.to_local(rec.vertices)
    ctr = rec.alignment.to_world(s, 0 * o, 0 * h + rec.centre_height_m)
    d = rec.vertices - ctr
    return np.linalg.norm(d, axis=1) - scene.cast(ctr, d).t


@pytest.mark.parametrize("known_axis", [True, False])
def test_reconstruction_within_2_mm_of_the_true_lining(scanned, known_axis):
    al, scene, cloud = scanned
    rec = reconstruct_tunnel(cloud, alignment=al if known_axis else None,
                             centre_height_m=1.3 if known_axis else None, cell_m=0.1,
                             cell_rad=np.deg2rad(2.0))
    err = _radial_error(rec, scene)
    ok = rec.support > 0
    assert np.sqrt(np.mean(err[ok] ** 2)) <= 0.002
    # The blind sector under the trolley is filled and flagged as extrapolated.
    assert 0.01 < rec.extrapolated_share < 0.2
    s, o, h = rec.alignment.to_local(rec.vertices[rec.support == 0])
    assert np.median(h - rec.centre_height_m) < 0                      # the floor
    mesh = trimesh.Trimesh(rec.vertices, rec.faces, process=False)
    assert mesh.is_winding_consistent and not mesh.is_watertight      # open portals
    assert rec.quality["median_m"] < 0.002


def test_faces_point_into_the_tunnel(scanned):
    al, scene, cloud = scanned
    rec = reconstruct_tunnel(cloud, alignment=al, centre_height_m=1.3, cell_m=0.2,
                             cell_rad=np.deg2rad(4.0))
    mesh = trimesh.Trimesh(rec.vertices, rec.faces, process=False)
    s, o, h = al.to_local(mesh.triangles_center)
    axis = al.to_world(s, 0 * o, 0 * h + 1.3)
    assert np.all(np.einsum("ij,ij->i", mesh.face_normals, axis - mesh.triangles_center) > 0)


def test_not_a_tunnel_is_reported():
    rng = np.random.default_rng(0)
    blob = rng.normal(0, 1, (5000, 3))
    blob /= np.linalg.norm(blob, axis=1, keepdims=True)
    with pytest.raises(ReconstructionError, match="could not find a tunnel axis"):
        reconstruct_tunnel(blob * 5)
    with pytest.raises(ReconstructionError, match="non-empty"):
        reconstruct_tunnel(np.empty((0, 3)), alignment=Alignment([straight(10.0)]))


def test_poisson_alternative_is_trimmed_and_close(scanned):
    """Open3D's Poisson (optional): closures at the portals removed, the lining within
    a few millimetres of the truth."""
    pytest.importorskip("open3d", reason="Poisson reconstruction needs the optional Open3D")
    from survey.clouds.reconstruct import poisson_tunnel
    al, scene, cloud = scanned
    v, f = poisson_tunnel(cloud, alignment=al, centre_height_m=1.3, depth=9)
    s, o, h = al.to_local(v)
    c_lo, c_hi = al.to_local(cloud)[0].min(), al.to_local(cloud)[0].max()
    assert s.min() >= c_lo - 1e-9 and s.max() <= c_hi + 1e-9        # no portal bulbs
    mesh = trimesh.Trimesh(v, f, process=False)
    assert not mesh.is_watertight                                  # open at the portals
    ctr = al.to_world(s, 0 * o, 0 * h + 1.3)
    d = v - ctr
    err = np.linalg.norm(d, axis=1) - scene.cast(ctr, d).t
    inner = (s > c_lo + 1.0) & (s < c_hi - 1.0) & np.isfinite(err)
    assert np.sqrt(np.mean(err[inner] ** 2)) < 0.01


@pytest.mark.parametrize("tilt_deg", [0.0, 2.0])
def test_profiles_tilted_across_the_axis_keep_their_end_rings(tilt_deg):
    """Profiles measured in planes that are not normal to the axis (an estimated axis
    drifts across the track): the end profiles reach beyond the axis's ends on one side.
    Their rings keep those points (the alignment extended straight), so the end rings
    are the true circle, not a chord across the missing side (as at Ringo's portal)."""
    from survey.clouds.axis import extend_chainage

    tilt = np.radians(tilt_deg)
    al = Alignment([straight(10.0)])
    phi = np.linspace(-np.pi, np.pi, 3600, endpoint=False)

    def r_of(a):                       # not a circle: a chord across a gap is wrong
        return 3.0 + 0.4 * np.cos(3 * a)

    rings = np.arange(0.0, 10.01, 1.0)
    # Ring k lies in the plane x = k + y tan(tilt) (a yaw of the scan plane); phi from
    # the crown, positive to the left (+y), as the mesher's angles.
    r = r_of(phi)
    pts = np.concatenate([np.stack([k + r * np.sin(phi) * np.tan(tilt), r * np.sin(phi),
                                    r * np.cos(phi)], 1) for k in rings])
    s = extend_chainage(al, pts, al.to_local(pts)[0])
    np.testing.assert_allclose(s, pts[:, 0], atol=1e-9)     # straight: chainage = x
    rec = reconstruct_tunnel(pts, alignment=al, rows_at=rings, cell_rad=np.radians(2.0),
                             min_points=1)
    v = rec.vertices.reshape(len(rings), -1, 3)
    radius = np.hypot(v[..., 1], v[..., 2])                 # about the axis (y = z = 0)
    assert rec.extrapolated_share == 0.0
    # A cell's median radius is the radius at its centre angle to within the change of
    # r over half a cell (1.2 m/rad x 1 deg = 2.1 cm); a chord across the lost half of
    # an end ring would be off by decimetres.
    np.testing.assert_allclose(radius, np.broadcast_to(r_of(rec.angles), radius.shape),
                               atol=0.025)
