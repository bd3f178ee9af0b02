"""Analysis: cloud-to-cloud and cloud-to-mesh distances, station planning, MLS studies,
trajectory errors (as evo computes them)."""

from .compare import Distances, ReferenceCloud, ReferenceMesh, cloud_to_cloud, cloud_to_mesh, distance_stats
from .planning import Plan, Planner, RoutePlanner, Thresholds, axis_stations, lining_cells
from .surface import RouteFrame, Surface, mesh_surface
from .study import Study, StudyRow
from .trajectory import RelativeError, TrajectoryErrors, align_origin, path_pairs, trajectory_errors

__all__ = ["Distances", "ReferenceCloud", "ReferenceMesh", "cloud_to_cloud",
           "cloud_to_mesh", "distance_stats", "Plan", "Planner", "RoutePlanner", "Thresholds",
           "RouteFrame", "Surface", "mesh_surface",
           "axis_stations", "lining_cells", "Study", "StudyRow", "RelativeError",
           "TrajectoryErrors", "align_origin", "path_pairs", "trajectory_errors"]
