"""Adjustment: Helmert transformations with their statistics, control points, MLS drift
correction and simulated SLAM drift."""

from .helmert import HelmertResult, fit_helmert, from_parameters
from .controlpoints import ControlPoints, match, read_control_points
from .drift import DriftCorrection, fit_drift, leave_one_out
from .slam import slam_trajectory, to_slam_frame, DriftedRun, SlamObservation, observe_slam

__all__ = ["DriftedRun", "SlamObservation", "observe_slam", "HelmertResult", "fit_helmert", "from_parameters", "ControlPoints", "match",
           "read_control_points", "DriftCorrection", "fit_drift", "leave_one_out",
           "slam_trajectory", "to_slam_frame"]
