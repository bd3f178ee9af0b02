"""The library functions that used to live inside commands: the triangle budget of
``mesh``, the detail layer of ``mesh --detail``, the plan summary of ``plan`` (plan.json)."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from survey.cli.main import main
from survey.clouds.detail import DETAIL_SUPPORT, attachment_tubes, with_detail_layer
from survey.clouds.reconstruct import reconstruct_tunnel, reconstruct_within_budget
from survey.clouds.segment import ATTACHMENT, segment_tunnel
from survey.errors import ReconstructionError
from survey.report.planning import plan_summary


@pytest.fixture(scope="module")
def lining(tmp_path_factory):
    """(tunnel, points sampled on lining, floor and cables between chainage 30 and 50)."""
    from survey.world.mesh import read_tunnel

    out = tmp_path_factory.mktemp("lib") / "tbm.ply"
    assert main(["tunnel", "-o", str(out), "--preset", "tbm", "--edge-length", "0.3",
                 "--quiet"]) == 0
    tun = read_tunnel(out)
    rng = np.random.default_rng(3)
    s0 = tun.vertex_chainage[tun.faces[:, 0]]
    window = np.flatnonzero((s0 > 30.0) & (s0 < 50.0))
    tri = tun.vertices[tun.faces[window[rng.integers(0, len(window), 150_000)]]]
    return tun, np.einsum("nk,nkj->nj", rng.dirichlet([1, 1, 1], len(tri)), tri)


def test_budget_fits_and_keeps_the_fine_mesh_when_it_fits(lining):
    tun, pts = lining
    kw = {"alignment": tun.alignment, "centre_height_m": 2.5, "cell_m": 0.25,
              "cell_rad": np.deg2rad(3.0)}
    fine = reconstruct_tunnel(pts, **kw)
    same = reconstruct_within_budget(pts, len(fine.faces), **kw)
    np.testing.assert_array_equal(same.vertices, fine.vertices)
    np.testing.assert_array_equal(same.faces, fine.faces)
    for budget in (len(fine.faces) // 3, 2000):
        rec = reconstruct_within_budget(pts, budget, **kw)
        assert 0 < len(rec.faces) <= budget
        # Coarser cells in both directions, the same grid kind (2 triangles per cell).
        assert np.diff(rec.chainages).mean() > np.diff(fine.chainages).mean()
        assert len(rec.angles) < len(fine.angles)
        assert len(rec.faces) == 2 * (len(rec.chainages) - 1) * len(rec.angles)


@pytest.mark.parametrize("budget, match", [(1, "reachable"), (0, "positive integer"),
                                           (2.5, "positive integer")])
def test_budget_refuses_what_it_cannot_do(lining, budget, match):
    tun, pts = lining
    with pytest.raises(ReconstructionError, match=match):
        reconstruct_within_budget(pts, budget, alignment=tun.alignment, centre_height_m=2.5,
                                  cell_m=0.5, cell_rad=np.deg2rad(4.0))


def test_detail_layer_is_the_lining_plus_the_tubes(lining):
    tun, pts = lining
    rec = reconstruct_tunnel(pts, alignment=tun.alignment, centre_height_m=2.5, cell_m=0.5,
                             cell_rad=np.deg2rad(4.0))
    got = with_detail_layer(rec, pts)
    # The same as segmenting and tubing by hand.
    cls = segment_tunnel(pts, alignment=rec.alignment, centre_height_m=rec.centre_height_m)
    tv, tf = attachment_tubes(pts[cls == ATTACHMENT], rec.alignment)
    n = len(rec.vertices)
    assert len(tf) > 0 and got.detail_faces == len(tf)
    np.testing.assert_array_equal(got.vertices[:n], rec.vertices)
    np.testing.assert_array_equal(got.vertices[n:], tv)
    np.testing.assert_array_equal(got.faces[:len(rec.faces)], rec.faces)
    np.testing.assert_array_equal(got.faces[len(rec.faces):], tf + n)
    assert (got.support[n:] == DETAIL_SUPPORT).all() and (got.support[:n] >= 0).all()
    assert got.faces.max() < len(got.vertices)


def test_detail_layer_writes_its_support(lining, tmp_path):
    from tests.iofiles import mesh_fields as read_ply

    tun, pts = lining
    rec = reconstruct_tunnel(pts, alignment=tun.alignment, centre_height_m=2.5, cell_m=0.5,
                             cell_rad=np.deg2rad(4.0))
    got = with_detail_layer(rec, pts)
    back = read_ply(got.write(tmp_path / "m.ply"))
    np.testing.assert_array_equal(back["faces"], got.faces)
    np.testing.assert_allclose(back["support"], got.support)


def test_plan_summary_is_plain_strict_data():
    from raytrace.fileio import json_text

    plans = [SimpleNamespace(name="every 5 m", chainages=np.array([0.0, 5.0, 10.0]),
                             coverage=np.float64(0.75), gaps=[{"area_m2": 1.0}] * 2,
                             offsets_m=np.zeros(3, dtype=np.float32),
                             stations=np.array([[0.0, 0, 1.5], [5, 0, 1.5], [10, 0, 1.5]])),
             SimpleNamespace(name="optimised", chainages=np.array([2.5]),
                             coverage=np.float32(0.5), gaps=[], offsets_m=np.array([1.0]),
                             stations=np.array([[2.5, 1.0, 1.5]]))]
    planner = SimpleNamespace(sensor=SimpleNamespace(name="zf_imager_5016"),
                              resolution="high")
    info = {"candidates": np.int64(9), "gap": float("nan"), "milp": None}
    s = plan_summary(plans, planner, info)
    assert s["sensor"] == "zf_imager_5016" and s["resolution"] == "high"
    assert s["plans"][0] == {"name": "every 5 m", "stations": 3, "coverage": 0.75,
                             "gaps": 2, "chainages_m": [0.0, 5.0, 10.0],
                             "offsets_m": [0.0, 0.0, 0.0],
                             "stations_xyz": [[0.0, 0.0, 1.5], [5.0, 0.0, 1.5],
                                              [10.0, 0.0, 1.5]]}
    assert type(s["plans"][0]["offsets_m"][0]) is float
    assert type(s["plans"][1]["coverage"]) is float
    assert type(s["optimisation"]["candidates"]) is int
    back = json.loads(json_text(s), parse_constant=lambda c: pytest.fail(c))
    assert back["optimisation"] == {"candidates": 9, "gap": None, "milp": None}
    assert plan_summary(plans, planner)["optimisation"] is None
