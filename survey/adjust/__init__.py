"""Adjustment: Helmert transformations with their statistics, control points, MLS drift
correction, simulated SLAM drift and real LiDAR odometry (KISS-ICP, GenZ-ICP)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from raytrace.lazy import lazy_exports_of

# The one list of public names (imported on first use; type checkers read it).
if TYPE_CHECKING:
    from .helmert import HelmertResult, fit_helmert, from_parameters
    from .controlpoints import ControlPoints, match, read_control_points, unmatched, unmatched_message
    from .snooping import Snooping, SnoopStep, data_snooping
    from .drift import DriftCorrection, fit_drift, leave_one_out
    from .slam import slam_trajectory, to_slam_frame, DriftedRun, SlamObservation, observe_slam, observe_control
    from .odometry import OdometryResult, odometry_trajectory, run_odometry

__getattr__, __dir__, __all__ = lazy_exports_of(__name__, __file__, extra=())
