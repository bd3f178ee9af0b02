"""Scale out: the execution layer (this process, a dask LocalCluster or an existing
dask cluster, the same results on each) and what runs on it: TLS campaigns (one file
per station and a manifest), drives split into time windows, and comparisons (C2C, C2M,
M3C2) tile by tile with a halo (``TileSpill``).

dask.distributed is optional (the extra ``cluster``) and imported only when a cluster
is asked for.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from raytrace.lazy import lazy_exports_of

# The one list of public names (imported on first use; type checkers read it).
if TYPE_CHECKING:
    from .execution import (CLUSTER_HINT, ClusterError, DaskExecutor, Executor, InProcess,
                            SceneRef, Shared, TaskProgress, call_shared,
                            numba_threads_per_worker, open_executor)
    from .campaign import (MANIFEST_FORMAT, MANIFEST_NAME, Campaign, Station, read_plan,
                           scan_stations, sha256_of, station_file, station_seed)
    from .windows import DRIVE_MANIFEST_FORMAT, Window, drive_windows, simulate_windows
    from .tiles import TileData, TileRef, TileSpill, tile_key_text
    from .m3c2_tiles import HALO_MARGIN_M, M3C2Store, halo_of, iter_subsample, m3c2_files
    from .compare import TiledDistances, spill_cloud, tiled_distances

__getattr__, __dir__, __all__ = lazy_exports_of(__name__, __file__, extra=())
