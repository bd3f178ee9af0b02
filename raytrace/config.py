"""Compile policy, tolerances and BVH build constants: the one place they live.

Kernels import these names; nothing else in the package spells a tolerance or a cost
as a literal. Changing a value here changes it everywhere (and invalidates the Numba
cache automatically, because the constants are globals of the kernel modules).
"""

from __future__ import annotations

import operator
import os

import numba

from .errors import ConfigError

# ---------------------------------------------------------------------------------------
# Compile policy
# ---------------------------------------------------------------------------------------
#: Cache compiled kernels on disk (``__pycache__``), so only the first run compiles.
#: Caveat: Numba invalidates a cached kernel only when *its own* source file changes.
#: After editing ``_kernels/intersect.py`` or ``traverse.py`` (inlined into ``traverse.py``
#: and ``cubemap.py``), delete the
#: ``*.nbi``/``*.nbc`` files or touch ``traverse.py``; a fresh clone never has a cache.
CACHE = True
#: ``fastmath`` is allowed in the BVH *builder* only (its result is a heuristic tree;
#: reassociation cannot make it wrong). DECISION: never in intersection or traversal —
#: reordering the Möller–Trumbore arithmetic breaks edge/vertex consistency between
#: neighbouring triangles, and NaN handling in the slab test relies on IEEE comparisons.
BUILD_FASTMATH = {"nsz", "arcp", "contract", "afn", "reassoc"}

#: IEEE semantics for division (1/0 = inf, no ZeroDivisionError check per division): the
#: slab test relies on 1/0 = inf for axis-parallel rays.
ERROR_MODEL = "numpy"

#: Rays handled sequentially by one worker before the next block is taken. Blocks are a
#: fixed size, independent of the thread count, so results never depend on it.
RAY_BLOCK = 256
#: Blocks handed to a worker at a time (Numba dynamic scheduling). Ray cost varies a lot
#: across a scan (rays down the tunnel axis visit more nodes), so static equal shares
#: leave one core idle; measured on the 1M-triangle benchmark tunnel: 1.5x -> ~2x scaling.
PRANGE_CHUNK = 8


def max_threads() -> int:
    """Most Numba worker threads this process may use (``NUMBA_NUM_THREADS``, fixed at
    start-up: all cores unless the environment variable says otherwise)."""
    # numba.config sets its attributes at run time, so type checkers cannot see them.
    return int(numba.config.NUMBA_NUM_THREADS)  # type: ignore[attr-defined]


def set_threads(n: int | None) -> int:
    """Set the number of Numba worker threads used by every parallel kernel.

    Results never depend on the count (rays are handed out in fixed-size blocks).

    Parameters
    ----------
    n : int or None
        Threads, between 1 and ``max_threads()``; ``None`` uses all of them.

    Returns
    -------
    int
        The thread count now in use.

    Raises
    ------
    ConfigError
        ``n`` is not a whole number or lies outside [1, ``max_threads()``].
    """
    top = max_threads()
    if n is None:
        n = top
    try:
        count = operator.index(n)
    except TypeError:
        raise ConfigError(f"Expected a whole-number thread count, got {n!r}; pass an int "
                          "or None for all cores.") from None
    if not 1 <= count <= top:
        raise ConfigError(
            f"Expected a thread count between 1 and {top}, got {count}; pass a smaller "
            "number or leave it unset to use all cores."
        )
    numba.set_num_threads(count)
    return count


def threads() -> int:
    """Number of Numba worker threads currently in use."""
    return int(numba.get_num_threads())


@numba.njit(cache=CACHE, parallel=True)
def _probe(n):  # pragma: no cover - trivial; compiled once, cached
    acc = 0
    for i in numba.prange(n):
        acc += i
    return acc


def threading_info() -> dict[str, str | int]:
    """Numba's threading layer and thread counts.

    Runs a tiny parallel kernel first, because Numba chooses the layer lazily.

    Returns
    -------
    dict
        ``threading_layer`` (str: "tbb", "omp" or "workqueue"), ``threads`` (int, in
        use) and ``max_threads`` (int, the most that may be set).
    """
    _probe(4)
    return dict(threading_layer=str(numba.threading_layer()), threads=threads(),
                max_threads=max_threads())


def _threads_from_environment() -> None:
    """Apply ``TUNNELSIM_THREADS`` (an int) when set, naming the variable on error."""
    value = os.environ.get("TUNNELSIM_THREADS")
    if value is None:
        return
    try:
        set_threads(int(value))
    except (ValueError, ConfigError) as exc:
        raise ConfigError(f"Expected the environment variable TUNNELSIM_THREADS to be a "
                          f"thread count between 1 and {max_threads()}, got {value!r}; "
                          "fix or unset it.") from exc


_threads_from_environment()

# ---------------------------------------------------------------------------------------
# Intersection tolerances (Möller & Trumbore 1997)
# ---------------------------------------------------------------------------------------
#: Barycentric slack: a hit is accepted when u >= -BARY, v >= -BARY, u + v <= 1 + BARY.
#: DECISION: a small positive slack makes rays aimed exactly at an edge or a vertex hit
#: (at least) one of the triangles sharing it, whatever the rounding of the two
#: triangles' separate tests; without it such rays can slip through a closed mesh. The
#: price is that a ray passing within ~BARY * edge length outside a triangle counts as a
#: hit on it. 1e-9 is ~10^6 ulps of a barycentric coordinate: far above float64
#: rounding, far below anything a laser scanner resolves (1e-9 of a 10 cm edge = 0.1 nm).
BARY = 1e-9

#: Triangles whose |e1 x e2| is below AREA_REL * (longest edge)^2 are zero-area
#: (collinear or repeated vertices) and are dropped at build time with a warning.
AREA_REL = 1e-14

#: Node boxes are stored as float32, rounded outward, then padded by BOX_PAD_REL times
#: the scene's largest extent so that rounding in the slab test cannot cull a box that
#: the exact ray touches (a hit on a box face or exactly at a shared vertex).
BOX_PAD_REL = 1e-6

#: Cube-map views (``_kernels/cubemap.py``): projected footprints are enlarged by this
#: much (in tan-angle units, ~rad) so that rounding in clipping and projection never
#: drops a candidate triangle. Large against float64 rounding and the BARY slack,
#: negligible against a cell (a 1024-cell face has cells of 2e-3).
CUBEMAP_PAD = 1e-6
#: A cell listing more triangles than this sends its rays through the BVH instead.
CUBEMAP_HOT = 48
#: Cells per cube face side: about CUBEMAP_CELLS_PER_TRI cells per triangle in all,
#: clamped to [CUBEMAP_MIN_G, CUBEMAP_MAX_G]. Measured on the bfo preset at 0.1 m
#: (0.81M triangles, a 4M-ray station, one thread): 4 -> 1 builds the map in 0.10 s
#: instead of 0.27 s (a quarter of the entries) and casts as fast (the smaller cell
#: arrays stay in cache; 0.25-2 all cast within 5 %).
CUBEMAP_CELLS_PER_TRI = 1.0
CUBEMAP_MIN_G = 64
CUBEMAP_MAX_G = 2048
#: Use a cube map for a single-origin batch when it has at least this many rays per
#: triangle, and per cell of the map (building one costs about as much as casting ~0.1
#: rays per triangle; on a small mesh the map's cells, at least 6 x CUBEMAP_MIN_G^2,
#: cost more than its triangles).
CUBEMAP_MIN_RAYS_PER_TRI = 0.5
#: ... and never fewer than this many rays: on a tiny mesh the rule above asked a map
#: for every run of one origin (a drive against a 2-face wall built 14,464 maps, 148 s).
CUBEMAP_MIN_RUN = 256
#: Give up on the cube map (use the BVH) when its lists would exceed this many entries
#: (4 bytes each): an origin right against large triangles.
CUBEMAP_MAX_ENTRIES = 64_000_000  # must stay below 2^31 (int32 offsets)
#: A map of at least this many triangles counts and lists its entries with one task a
#: thread (``cubemap.count_entries``, ``fill_entries``; the same lists), smaller ones
#: serially: on this shared 2-core VM each parallel region may wait milliseconds for a
#: descheduled thread, more than a small map's lists take. Measured 2026-11-27 at load
#: average 4 (bfo, 640x480 frames, a near map of ~31k triangles): count + fill 14-18 ms
#: of wall clock a frame in parts, 3.8-8 ms serially; a station's whole map (0.81M
#: triangles, ~12 ms of serial count + fill) keeps its parts.
CUBEMAP_PARALLEL_MIN_TRIS = 65_536

#: Near maps (``_kernels/nearmap.py``): a run of rays from one origin too short for a
#: map of the whole mesh (fewer than CUBEMAP_MIN_RAYS_PER_TRI rays a triangle: a camera
#: frame) but at least NEARMAP_MIN_RUN long gets a cube map of only the triangles
#: nearest to the origin inside the cone of its directions; rays whose hit may lie
#: beyond them walk the BVH. Measured on the bfo preset (0.81M triangles), pinhole
#: frames along the tunnel, one thread, CPU time a ray (BVH / near map): 1,024 rays
#: 350 / 1008 ns, 4,096 339 / 471, 12,288 339 / 354, 49,152 304 / 294, 307,200 (640x480)
#: 245 / 151: the map's fixed costs are repaid from ~40k rays.
NEARMAP_MIN_RUN = 32_768
#: Triangles collected per ray of the run (at least NEARMAP_MIN_TRIS).
NEARMAP_TRIS_PER_RAY = 0.1
NEARMAP_MIN_TRIS = 4096
#: A near map has about NEARMAP_CELLS_PER_TRI cells per collected triangle inside the
#: cone of directions, and at most NEARMAP_MAX_CELLS_PER_TRI per triangle over the
#: whole grid. Measured (bfo, one thread, CPU time per ray including the map): the
#: camera frame 160 / 161 ns at 4 / 16 (NEARMAP_TRIS_PER_RAY 0.1; 0.5 gave 217-240,
#: 0.05 gave 165-186: too many rays beyond the radius); a 640k-ray station 125 / 118 /
#: 115 ns at 1 / 2 / 4, a 4M-ray station 100 / 101 / 113 ns (the whole map: 237 and
#: 104-114 ns). The lists are filled serially, so fewer cells also wait less on 2 cores.
NEARMAP_CELLS_PER_TRI = 4.0
NEARMAP_MAX_CELLS_PER_TRI = 16.0

#: Batches of at least this many rays with their own origins are cast in Morton order
#: of the origins (``_kernels/order.py``): measured on the 1M-triangle benchmark tunnel
#: with 2M random rays, ~1.2 -> ~1.5 Mrays/s (timings on this VM vary ~30 %); the sort
#: costs ~20 ns a ray.
ORDER_MIN_RAYS = 65_536
#: Grid for the Morton key: 2^ORDER_BITS cells per axis of the scene's box.
ORDER_BITS = 7
#: The same for ``Scene.cast`` (closest hits through the BVH); ``ORDER_BITS`` stays for
#: ``occluded`` and ``closest``. DECISION: 5 (cells of ~9 m on the 300 m bfo preset):
#: measured on bfo (1M random rays from origins within 0.5 m of the centreline, one
#: quiet 2-core run, wall ns a ray of the traversal with 7 / 5 bits / no order):
#: origins along 8 m 233 / 208 / 213, 30 m 288 / 229 / 220, 100 m 309 / 292 / 279,
#: 250 m 351 / 354 / 382. Finer cells scatter the kernel's reads of the rays and writes
#: of the answers over memory for little tree locality, and their counting sort over
#: 2^21 buckets costs ~15 ns a ray (5 bits: ~2). Issue 33.
CAST_ORDER_BITS = 5
#: A batch keeps its own order when, on average, at least ORDER_RUN consecutive
#: origins stay within one such cell's width of each other (a drive's rays in time
#: order): sorting them costs ~20-60 ns a ray and gains nothing (issue 16).
ORDER_RUN = 64

# ---------------------------------------------------------------------------------------
# BVH build (Wald 2007, "On fast construction of SAH-based bounding volume hierarchies")
# ---------------------------------------------------------------------------------------
#: Number of centroid bins per axis in the binned SAH sweep.
SAH_BINS = 16
#: Bin along all three axes (Wald 2007) or only along the longest centroid extent.
#: Measured on the 1M-triangle benchmark tunnel: longest-axis-only builds 28 % faster
#: (0.64 vs 0.89 s) but raises the SAH cost 11 % and casts 5-20 % slower; a scene is
#: built once and cast many times, so all axes is the default.
SAH_ALL_AXES = True
#: Cost of one traversal step relative to C_ISECT; the triangle test is float64
#: Möller–Trumbore. Measured on the 1M-triangle benchmark tunnel
#: (benchmarks/bench_raycast.py) with the earlier 4-wide records: C_trav 1 -> 3 with
#: leaves up to 16 gives mean leaves of ~4.8 instead of ~2, builds 25 % faster, halves
#: the node memory and casts as fast or faster (within this machine's ~30 % timing
#: noise). Not re-tuned for the 8-wide records (one packed 8-box test a step, issue 33).
SAH_C_TRAV = 3.0
#: Cost of one ray-triangle test.
SAH_C_ISECT = 1.0
#: A node with at most this many triangles may become a leaf when SAH says so.
MAX_LEAF_SIZE = 16
#: Parallel build (``_kernels/build.py``): nodes of more than
#: max(BUILD_TASK_MIN, m // BUILD_TASKS) triangles are split one at a time as tasks on a
#: shared queue; smaller ones are built whole by the worker that reaches them. The tree
#: does not depend on either value (tests/raytrace/test_build.py). DECISION: 4096 rows
#: (m // 256 above ~1M triangles): a subtree of that size takes ~1 ms, so the workers
#: finish within about that of each other (the earlier m // 16 suited a largest-first
#: list of subtrees fixed in advance, which the queue replaced). Measured on the bfo
#: preset (0.81M triangles, 2 threads, 8 alternated rounds, load ~5): 4096 and m // 16
#: tie (0.38 / 0.37 s CPU, 0.77 / 0.74 s wall median).
BUILD_TASKS = 256
BUILD_TASK_MIN = 4096
#: A node whose triangles all share one centroid cannot be split by position; it becomes
#: a leaf if it has at most this many, otherwise it is split in two by index.
MAX_LEAF_SIZE_FORCED = 32

__all__ = [
    "set_threads", "threads", "max_threads", "threading_info",
    "CACHE", "BUILD_FASTMATH", "ERROR_MODEL", "RAY_BLOCK", "PRANGE_CHUNK",
    "BARY", "AREA_REL", "BOX_PAD_REL",
    "CUBEMAP_PAD", "CUBEMAP_HOT", "CUBEMAP_CELLS_PER_TRI", "CUBEMAP_MIN_G", "CUBEMAP_MAX_G",
    "CUBEMAP_MIN_RAYS_PER_TRI", "CUBEMAP_MIN_RUN", "CUBEMAP_MAX_ENTRIES",
    "CUBEMAP_PARALLEL_MIN_TRIS",
    "NEARMAP_MIN_RUN", "NEARMAP_TRIS_PER_RAY", "NEARMAP_MIN_TRIS",
    "NEARMAP_CELLS_PER_TRI", "NEARMAP_MAX_CELLS_PER_TRI",
    "ORDER_MIN_RAYS",
    "ORDER_BITS",
    "CAST_ORDER_BITS",
    "ORDER_RUN",
    "SAH_BINS", "SAH_ALL_AXES", "SAH_C_TRAV", "SAH_C_ISECT", "MAX_LEAF_SIZE", "BUILD_TASKS",
    "BUILD_TASK_MIN", "MAX_LEAF_SIZE_FORCED",
]
