"""Segmentation of a simulated scan of a generated tunnel against the generator's
labels (the truth behind every simulated point's triangle)."""

from __future__ import annotations

import numpy as np
import pytest

from raytrace import Scene
from sensors import Settings, Trajectory, load_sensor, simulate_drive
from sensors.spec import SPEC_DIR
from survey.world import features as F
from survey.world.alignment import Alignment, curve, straight
from survey.world.profiles import horseshoe
from survey.clouds.segment import ATTACHMENT, FLOOR, LINING, NOISE, OBJECT, segment_tunnel
from survey.world.mesh import LABEL
from survey.world.generator import make_tunnel


@pytest.fixture(scope="module")
def scan(tmp_path_factory):
    al = Alignment([straight(15.0), *curve(0.15, 200.0, 5.0), straight(10.0)])
    feats = [F.Cable("left", 1.5, radius_m=0.02, start_m=1.0, end_m=40.0),
             F.Cable("left", 1.6, radius_m=0.015, start_m=1.0, end_m=40.0),
             F.Drainage(-0.7, 0.25, 0.15), F.Bolts((0.0,), spacing_m=2.0)]
    tun = make_tunnel(al, horseshoe(2.8), edge_length_m=0.05, roughness_rms_m=0.002,
                      features=feats, seed=3)
    c0, c1 = al.chainage_range
    s = np.arange(c0 + 0.5, c1 - 0.5, 0.25)
    traj = Trajectory.along_polyline(al.to_world(s, -0.3, 1.0), 1.0, rate_hz=50)
    text = (SPEC_DIR / "zf_profiler_9012.toml").read_text()
    text = text.replace("profile_rate_hz = 200.0", "profile_rate_hz = 20.0")
    text = text.replace("points_per_profile = 5000", "points_per_profile = 1500")
    text = text.replace('name = "zf_profiler_9012"', 'name = "seg_profiler"')
    toml = tmp_path_factory.mktemp("spec") / "p.toml"
    toml.write_text(text)
    pts = np.concatenate(list(simulate_drive(Scene(tun.vertices, tun.faces), load_sensor(toml),
                                             traj, settings=Settings(angle_jitter=False,
                                                                     detection=False),
                                             seed=1)))
    truth = tun.labels[pts["triangle"]]
    return al, np.stack([pts["x"], pts["y"], pts["z"]], 1), truth


def test_segmentation_recovers_the_generator_labels(scan):
    al, xyz, truth = scan
    cls = segment_tunnel(xyz, alignment=al, centre_height_m=1.3)
    want = np.full(len(truth), LINING)
    want[np.isin(truth, [LABEL["floor"], LABEL["wet_floor"], LABEL["drainage"]])] = FLOOR
    want[np.isin(truth, [LABEL["cable"], LABEL["bolt"], LABEL["prism"]])] = ATTACHMENT
    assert np.mean(cls == want) >= 0.95
    for c in (LINING, FLOOR, ATTACHMENT):                 # every class is found
        assert np.mean(cls[want == c] == c) > 0.8, c
    assert np.mean(cls == OBJECT) < 0.01


def test_objects_and_noise_are_separated(scan):
    al, xyz, truth = scan
    rng = np.random.default_rng(0)
    person = al.to_world(np.full(500, 20.0), rng.uniform(-0.2, 0.2, 500),
                         rng.uniform(0.9, 1.7, 500))   # a torso near the axis
    s, o, h = al.to_local(xyz[:300])
    behind = xyz[:300] + (xyz[:300] - al.to_world(s, 0 * o, 0 * h + 1.3)) * 0.2
    cls = segment_tunnel(np.concatenate([xyz, person, behind]), alignment=al,
                         centre_height_m=1.3)
    assert np.mean(cls[len(xyz):len(xyz) + 500] == OBJECT) > 0.95
    assert np.mean(cls[len(xyz) + 500:] == NOISE) > 0.95


def test_detail_layer_recovers_the_cables(scan):
    """Attachment points become closed tubes at the cables' true positions and radii
    (the seed study's meshes lost its four cables)."""
    import trimesh

    from survey.clouds.detail import attachment_tubes
    from survey.world.profiles import horseshoe
    al, xyz, truth = scan
    cls = segment_tunnel(xyz, alignment=al, centre_height_m=1.3)
    v, f = attachment_tubes(xyz[cls == ATTACHMENT], al)
    mesh = trimesh.Trimesh(v, f, process=False)
    bodies = [b for b in mesh.split(only_watertight=False) if b.area > 0.5]
    assert len(bodies) >= 2
    prof = horseshoe(2.8)
    want = []
    for height, r in ((1.5, 0.02), (1.6, 0.015)):
        t = prof.t_at_height("left", height)
        want.append((prof.points(t) - prof.normals(t) * (0.03 + r), r))
    for (c, r) in want:
        best = None
        for b in bodies:
            s, o, h = al.to_local(b.vertices)
            centre = np.array([np.median(o), np.median(h)])
            if best is None or np.linalg.norm(centre - c) < np.linalg.norm(best[0] - c):
                best = (centre, np.median(np.hypot(o - centre[0], h - centre[1])), b)
        centre, radius, body = best
        assert np.linalg.norm(centre - c) < 0.01, (centre, c)
        assert abs(radius - r) < 0.006, (radius, r)
        assert body.is_watertight and body.is_winding_consistent and body.volume > 0


def test_bad_segment_and_detail_input(tmp_path):
    from survey.clouds.detail import attachment_tubes
    from survey.errors import ReconstructionError
    from sensors.io.errors import TunnelFileError
    from survey.world.mesh import read_tunnel
    al = Alignment([straight(10.0)])
    with pytest.raises(ReconstructionError, match="non-empty finite cloud"):
        segment_tunnel(np.empty((0, 3)), alignment=al)
    with pytest.raises(ReconstructionError, match="shape"):
        segment_tunnel(np.zeros((5, 2)), alignment=al)
    v, f = attachment_tubes(np.zeros((3, 3)), al)          # too few points: no tube
    assert v.shape == (0, 3) and f.shape == (0, 3)
    (tmp_path / "t.ply").write_bytes(b"ply\n")
    with pytest.raises(TunnelFileError, match="metadata file"):
        read_tunnel(tmp_path / "t.ply")
    (tmp_path / "t.json").write_text('{"format": "other"}')
    with pytest.raises(TunnelFileError, match="format"):
        read_tunnel(tmp_path / "t.ply")
