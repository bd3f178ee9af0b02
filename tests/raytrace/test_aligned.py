"""Cache-line aligned records (``raytrace/aligned.py``) and aligned scene files
(``fileio.savez_aligned``): the alignment holds after a build, a save and a mapped load;
files written before (plain ``np.savez``) still load, with aligned records, and cast the
same; the aligned .npz is read back by NumPy itself, array for array."""

from __future__ import annotations

import struct
import zipfile

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from raytrace import Scene
from raytrace.aligned import as_aligned, empty_aligned
from raytrace.fileio import atomic_writer, npz_memmap, savez_aligned
from raytrace.shapes import tunnel_tube

_DTYPES = st.sampled_from([np.float32, np.float64, np.int32, np.int64, np.uint8,
                           np.int16, np.complex128])


@pytest.fixture(scope="module")
def tube():
    v, f = tunnel_tube(6_000, length_m=30.0, roughness_m=0.002, seed=5)
    return Scene(v, f)


def _data_offsets(path):
    """File offset of each member's array data, read from the zip local headers and the
    .npy headers (independently of fileio.npz_memmap)."""
    out = {}
    with zipfile.ZipFile(path) as zf, open(path, "rb") as fh:
        for info in zf.infolist():
            fh.seek(info.header_offset)
            local = fh.read(30)
            n_name, n_extra = struct.unpack("<HH", local[26:30])
            start = info.header_offset + 30 + n_name + n_extra
            fh.seek(start)
            magic = fh.read(8)
            assert magic[:6] == b"\x93NUMPY"
            (n_head,) = struct.unpack("<H", fh.read(2))
            out[info.filename[:-4]] = start + 10 + n_head
    return out


@given(shape=st.lists(st.integers(0, 9), min_size=1, max_size=3), dtype=_DTYPES,
       align=st.sampled_from([1, 2, 8, 16, 64, 256, 4096]))
def test_empty_aligned_starts_on_the_boundary(shape, dtype, align):
    a = empty_aligned(tuple(shape), dtype, align)
    assert a.shape == tuple(shape) and a.dtype == np.dtype(dtype)
    assert a.flags.c_contiguous and a.flags.writeable
    assert a.size == 0 or a.ctypes.data % align == 0
    a[...] = 1          # the whole view is ours to write
    assert (a == 1).all()


@pytest.mark.parametrize("align", [0, 3, 48, -64])
def test_empty_aligned_refuses_an_alignment_not_a_power_of_two(align):
    with pytest.raises(ValueError, match="power of two"):
        empty_aligned((4,), np.float32, align)


@pytest.mark.parametrize("align", [0, 3, 128, -64])
def test_savez_aligned_refuses_an_alignment_the_npy_header_cannot_keep(tmp_path, align):
    with open(tmp_path / "a.npz", "wb") as fh, \
            pytest.raises(ValueError, match="power of two up to 64"):
        savez_aligned(fh, {"a": np.zeros(3)}, align)


def test_as_aligned_copies_only_what_is_off_the_line():
    buf = empty_aligned((1024 + 64,), np.uint8)
    on = buf[:1024].view(np.float32)
    off = buf[16:16 + 1024].view(np.float32)
    off[...] = np.arange(off.size, dtype=np.float32)
    assert as_aligned(on) is on
    got = as_aligned(off)
    assert got is not off and got.ctypes.data % 64 == 0
    np.testing.assert_array_equal(got, off)


@settings(max_examples=30, deadline=None)
@given(arrays=st.dictionaries(
    st.text("abcdefghijklmnopqrstuvwxyz_", min_size=1, max_size=40),
    hnp.arrays(_DTYPES, hnp.array_shapes(min_dims=0, max_dims=3, max_side=7)),
    min_size=1, max_size=5))
def test_savez_aligned_is_an_npz_numpy_reads_back(tmp_path_factory, arrays):
    """Round trip through NumPy's own reader, every member's data on a 64-byte file
    offset, and the memory map of it equal too."""
    path = tmp_path_factory.mktemp("npz") / "a.npz"
    with atomic_writer(path) as fh:
        savez_aligned(fh, arrays)
    with np.load(path, allow_pickle=False) as z:
        assert sorted(z.files) == sorted(arrays)
        for k, a in arrays.items():
            assert z[k].dtype == a.dtype and z[k].shape == a.shape
            np.testing.assert_array_equal(z[k], a)
    offsets = _data_offsets(path)
    assert all(off % 64 == 0 for off in offsets.values()), offsets
    mapped = npz_memmap(path, tuple(arrays))
    for k, a in arrays.items():
        np.testing.assert_array_equal(mapped[k], a)
    assert zipfile.ZipFile(path).testzip() is None


def test_a_built_saved_and_mapped_scene_keeps_its_records_on_a_cache_line(tube, tmp_path):
    assert tube._nodes.ctypes.data % 64 == 0
    path = tube.save(tmp_path / "t.npz")
    assert all(off % 64 == 0 for off in _data_offsets(path).values())
    mapped = Scene.load(path, mmap=True)
    assert isinstance(mapped._nodes, np.memmap)          # still a map, not a copy
    assert mapped._nodes.ctypes.data % 64 == 0
    assert Scene.load(path)._nodes.ctypes.data % 64 == 0


def test_an_unpickled_scene_keeps_its_records_on_a_cache_line(tube):
    """What the cluster's workers receive (``Executor.share`` pickles the scene)."""
    import pickle

    for _ in range(4):   # a fresh allocation lands anywhere; try a few
        again = pickle.loads(pickle.dumps(tube))
        assert again._nodes.ctypes.data % 64 == 0
        np.testing.assert_array_equal(again._nodes.view(np.int32), tube._nodes.view(np.int32))


def test_a_file_written_before_loads_with_aligned_records_and_casts_the_same(tube,
                                                                             tmp_path):
    """A scene file of the same format written by plain ``np.savez`` (the writer before
    the aligned one): its records land off the line in the map and are copied."""
    path = tube.save(tmp_path / "new.npz")
    with np.load(path) as z:
        members = {k: z[k] for k in z.files}
    old = tmp_path / "old.npz"
    with open(old, "wb") as fh:
        np.savez(fh, **members)
    assert _data_offsets(old)["nodes"] % 64 != 0      # the case this test is about
    rng = np.random.default_rng(3)
    o = np.stack([rng.uniform(1, 29, 20_000), rng.uniform(-1, 1, 20_000),
                  rng.uniform(-1, 1, 20_000)], 1)
    d = rng.standard_normal((20_000, 3))
    want = tube.cast(o, d)
    for mmap in (False, True):
        again = Scene.load(old, mmap=mmap)
        assert again._nodes.ctypes.data % 64 == 0
        got = again.cast(o, d)
        for name in ("t", "triangle", "u", "v"):
            np.testing.assert_array_equal(getattr(got, name), getattr(want, name))
