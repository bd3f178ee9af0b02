"""Adjustment: Helmert transformations with their statistics, control points, MLS drift
correction, simulated SLAM drift and real LiDAR odometry (KISS-ICP, GenZ-ICP)."""

from .helmert import HelmertResult, fit_helmert, from_parameters
from .controlpoints import ControlPoints, match, read_control_points, unmatched, unmatched_message
from .snooping import Snooping, SnoopStep, data_snooping
from .drift import DriftCorrection, fit_drift, leave_one_out
from .slam import slam_trajectory, to_slam_frame, DriftedRun, SlamObservation, observe_slam, observe_control
from .odometry import OdometryResult, platform_trajectory, run_odometry

__all__ = ["DriftedRun", "SlamObservation", "observe_slam", "HelmertResult", "fit_helmert", "from_parameters", "ControlPoints", "match",
           "read_control_points", "DriftCorrection", "fit_drift", "leave_one_out",
           "slam_trajectory", "to_slam_frame", "observe_control", "OdometryResult",
           "platform_trajectory", "run_odometry", "unmatched", "unmatched_message",
           "Snooping", "SnoopStep", "data_snooping"]
