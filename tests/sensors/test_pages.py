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


# ------------------------------------------------------------------ held_heap (glibc)
class _Recorder:
    """Stands in for glibc: records mallopt and malloc_trim calls."""

    def __init__(self):
        self.calls = []

    def mallopt(self, param, value):
        self.calls.append(("mallopt", param, value))
        return 1

    def malloc_trim(self, pad):
        self.calls.append(("trim", pad))
        return 1


@pytest.fixture
def libc(monkeypatch):
    rec = _Recorder()
    monkeypatch.setattr(_pages, "_LIBC", rec)
    for name in _pages.USER_TUNING:
        monkeypatch.delenv(name, raising=False)
    return rec


HELD = [("mallopt", _pages.M_MMAP_THRESHOLD, _pages.HELD_MMAP_BYTES),
        ("mallopt", _pages.M_TRIM_THRESHOLD, _pages.HELD_TRIM_BYTES)]
AFTER = [("mallopt", _pages.M_MMAP_THRESHOLD, _pages.AFTER_MMAP_BYTES),
         ("mallopt", _pages.M_TRIM_THRESHOLD, _pages.AFTER_TRIM_BYTES), ("trim", 0)]


def test_the_outermost_block_holds_the_heap_and_gives_it_back_after(libc):
    a, b = _pages.held_heap(), _pages.held_heap()
    a.__enter__()
    assert libc.calls == HELD
    b.__enter__()                 # a second run iterated beside the first
    a.__exit__(None, None, None)  # ... and the first one ends before it
    assert libc.calls == HELD
    b.__exit__(None, None, None)
    assert libc.calls == HELD + AFTER
    with pytest.raises(KeyError), _pages.held_heap():
        raise KeyError("boom")
    assert libc.calls == 2 * (HELD + AFTER)  # set back after an exception too


@pytest.mark.parametrize("name", _pages.USER_TUNING)
def test_a_user_who_tuned_malloc_is_left_alone(libc, monkeypatch, name):
    monkeypatch.setenv(name, "1")
    with _pages.held_heap():
        pass
    assert libc.calls == []


def test_a_pass_holds_the_heap_once_and_an_early_stop_gives_it_back(scene, libc):
    traj = Trajectory.along_polyline([[5.0, 0.0, 1.4], [20.0, 0.0, 1.4]], 2.0,
                                     rate_hz=50)
    run = simulate_drive(scene, "velodyne_vlp16", traj, seed=4, t_end=0.2,
                         chunk_pulses=16_000, cache_bytes=0)
    held = np.concatenate(list(run))
    assert libc.calls == HELD + AFTER          # once for the pass, not per chunk
    it = iter(run)
    next(it)
    assert libc.calls[-2:] == HELD
    it.close()                                 # a consumer that stops early
    assert libc.calls[-3:] == AFTER
    part = list(run.chunks(3_000, 20_000))
    assert libc.calls[-5:] == HELD + AFTER
    # The points are the same without it (pages never change a result).
    real = _pages._LIBC
    try:
        _pages._LIBC = None
        assert held.tobytes() == np.concatenate(list(run)).tobytes()
        assert (np.concatenate(part).tobytes() ==
                np.concatenate(list(run.chunks(3_000, 20_000))).tobytes())
    finally:
        _pages._LIBC = real


FAULTS = r"""
import resource, sys
import numpy as np
from sensors import _pages

def faults(n):
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    a = np.ones(n)           # allocates and touches every page
    a = None
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before

n = (96 << 20) // 8          # 96 MiB: above glibc's largest dynamic mmap threshold
with _pages.transient_pages():
    with _pages.held_heap():
        first, again = faults(n), faults(n)
    after = faults(n)
print(first, again, after)
"""


@pytest.mark.skipif(_pages._LIBC is None, reason="glibc's malloc only")
def test_freed_memory_is_reused_inside_and_given_back_after(tmp_path):
    """The mechanism on the real allocator, in a fresh process (nothing freed before):
    inside the block a freed 96 MiB array's pages serve the next one without faults;
    after it, the memory went back to the kernel and is faulted in again."""
    import os
    import subprocess
    import sys
    env = {k: v for k, v in os.environ.items() if k not in _pages.USER_TUNING}
    out = subprocess.run([sys.executable, "-c", FAULTS], capture_output=True, text=True,
                         env=env, check=True, timeout=120).stdout.split()
    first, again, after = (int(v) for v in out)
    assert first >= 48, out              # 96 MiB: 48 faults even as 2 MiB huge pages
    assert again <= first // 10, out     # reused: hardly a fault
    assert after >= first // 2, out      # given back: faulted in again
