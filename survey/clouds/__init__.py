"""Point clouds: chunked file I/O, filters, segmentation, the tunnel axis and unrolling,
reconstruction of the lining and of attachments, of spaces that are not tubes (solid), simulated drives read back for SLAM."""

from sensors.io.clouds import annotate_las, cloud_bounds, iter_points, map_cloud, write_points_las, read_points, read_reference
from .preprocess import VoxelGrid, radius_outliers, statistical_outliers, voxel_down_sample
from .axis import (LiningExtent, estimate_axis, extend_chainage, lining_extent, tunnel_frame,
                   unroll, unroll_extended)
from .segment import CLASS_NAMES, TERRAIN, segment_tunnel
from .reconstruct import ReconstructedTunnel, poisson_tunnel, reconstruct_tunnel, reconstruct_within_budget
from .detail import attachment_tubes, DetailedMesh, with_detail_layer
from .solid import ScannerVoxelGrid, SolidMesh, nearest_scanner, reconstruct_solid
from .scanners import iter_scanned, read_positions, station_position
from .drives import DriveFile, ScanFrame, frames_from_points, iter_frames, open_drive, replace_drive

__all__ = ["read_points", "read_reference", "DetailedMesh", "with_detail_layer", "reconstruct_within_budget", "annotate_las", "cloud_bounds", "iter_points", "map_cloud", "write_points_las",
           "VoxelGrid", "radius_outliers", "statistical_outliers", "voxel_down_sample",
           "estimate_axis", "tunnel_frame", "unroll", "CLASS_NAMES", "segment_tunnel",
           "LiningExtent", "extend_chainage", "lining_extent", "unroll_extended", "TERRAIN",
           "ReconstructedTunnel", "poisson_tunnel", "reconstruct_tunnel",
           "attachment_tubes", "DriveFile", "ScanFrame", "frames_from_points", "iter_frames", "open_drive",
           "replace_drive", "ScannerVoxelGrid", "SolidMesh", "nearest_scanner",
           "reconstruct_solid", "iter_scanned", "read_positions", "station_position"]
