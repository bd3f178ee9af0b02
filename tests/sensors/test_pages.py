"""``sensors._pages.transient_pages``: the simulation loop turns NumPy's huge-page hint
off while a chunk is simulated (issue 33's drive rows: a third of the CPU time was page
faults) and puts the user's setting back. Checked against NumPy's own switch (which
returns the setting it replaces), and the points against a simulation with the switch
absent: pages never change a result."""

from __future__ import annotations

import numpy as np
import pytest

from raytrace import Scene
from raytrace.shapes import tunnel_tube
from sensors import Trajectory, _pages, simulate_drive, simulate_station


def _setting():
    """NumPy's current huge-page setting, read through its switch (set back at once)."""
    previous = _pages._SWITCH(True)
    _pages._SWITCH(previous)
    return bool(previous)


@pytest.fixture
def switch_log(monkeypatch):
    """NumPy's switch wrapped to record the setting each chunk was simulated under."""
    seen = []
    real = _pages._SWITCH
    assert real is not None   # NumPy 1.20+ on every platform has it

    def recording(enabled):
        seen.append(bool(enabled))
        return real(enabled)

    monkeypatch.setattr(_pages, "_SWITCH", recording)
    return seen


@pytest.mark.parametrize("user", [True, False])
def test_the_hint_is_off_inside_and_the_users_setting_back_after(user):
    before = _pages._SWITCH(user)
    try:
        with _pages.transient_pages():
            assert _setting() is False
        assert _setting() is user
        with pytest.raises(KeyError), _pages.transient_pages():
            raise KeyError("boom")
        assert _setting() is user          # restored after an exception too
    finally:
        _pages._SWITCH(before)


def test_without_numpys_switch_it_does_nothing(monkeypatch):
    monkeypatch.setattr(_pages, "_SWITCH", None)
    with _pages.transient_pages():
        pass


@pytest.fixture(scope="module")
def scene():
    return Scene(*tunnel_tube(4_000, length_m=30.0, seed=2))


def test_each_chunk_runs_without_the_hint_and_the_points_do_not_change(
        scene, switch_log, monkeypatch):
    traj = Trajectory.along_polyline([[5.0, 0.0, 1.4], [20.0, 0.0, 1.4]], 2.0,
                                     rate_hz=50)
    run = simulate_drive(scene, "velodyne_vlp16", traj, seed=4, t_end=0.2,
                         chunk_pulses=16_000, cache_bytes=0)
    seen_inside = []
    original = type(run)._chunk

    def chunk(self, *a, **kw):
        if _pages._SWITCH is not None:
            seen_inside.append(_setting())
        return original(self, *a, **kw)

    monkeypatch.setattr(type(run), "_chunk", chunk)
    with_switch = np.concatenate(list(run))
    part = np.concatenate(list(run.chunks(3_000, 20_000)))
    n_chunks = len(seen_inside)
    assert n_chunks >= 3 and not any(seen_inside)   # every chunk: hint off
    # Each block switched off, then back to what it found.
    assert switch_log[0::2] == [False] * (len(switch_log) // 2)
    monkeypatch.setattr(_pages, "_SWITCH", None)
    without = np.concatenate(list(run))
    assert with_switch.tobytes() == without.tobytes()
    assert part.tobytes() == np.concatenate(list(run.chunks(3_000, 20_000))).tobytes()


def test_a_station_file_is_the_same_with_and_without_the_switch(scene, tmp_path,
                                                                monkeypatch):
    run = simulate_station(scene, "zf_imager_5016", [10.0, 0.0, 1.4],
                           resolution="preview", seed=2, cache_bytes=0)
    a = run.write(tmp_path / "a.las")
    monkeypatch.setattr(_pages, "_SWITCH", None)
    b = run.write(tmp_path / "b.las")
    assert a["points"] == b["points"] > 0
    assert (tmp_path / "a.las").read_bytes() == (tmp_path / "b.las").read_bytes()
