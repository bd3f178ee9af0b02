"""Point clouds: chunked file I/O, filters, segmentation, the tunnel axis and unrolling,
reconstruction of the lining and of attachments, of spaces that are not tubes (solid), simulated drives read back for SLAM,
colour and temperature carried from coloured clouds onto mesh vertices."""

from __future__ import annotations

from typing import TYPE_CHECKING

from raytrace.lazy import lazy_exports_of

# The one list of public names (imported on first use; type checkers read it).
if TYPE_CHECKING:
    from .preprocess import VoxelGrid, radius_outliers, statistical_outliers, voxel_down_sample
    from .axis import (LiningExtent, estimate_axis, extend_chainage, lining_extent, tunnel_frame,
                       unroll, unroll_extended)
    from .segment import CLASS_NAMES, TERRAIN, segment_tunnel
    from .reconstruct import ReconstructedTunnel, poisson_tunnel, reconstruct_tunnel, reconstruct_within_budget
    from .detail import attachment_tubes, DetailedMesh, with_detail_layer
    from .solid import ScannerVoxelGrid, SolidMesh, nearest_scanner, reconstruct_solid
    from .scanners import iter_scanned, read_positions, station_position
    from .drives import DriveFile, ScanFrame, frames_from_points, iter_frames, open_drive, replace_drive
    from .colour import (AppearanceCloud, AppearanceGrid, VertexAppearance, appearance_radius,
                         transfer_appearance)

__getattr__, __dir__, __all__ = lazy_exports_of(__name__, __file__, extra=())
