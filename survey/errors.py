"""Errors of the survey package.

Every error is a ``TunnelsimError`` (the root shared by raytrace, sensors and survey) and
a ``ValueError``. Messages follow one pattern: what was expected, what was got, what to
do.
"""

from __future__ import annotations

from raytrace.errors import TunnelsimError


class ControlPointError(TunnelsimError, ValueError):
    """A control-point file is malformed, or two files do not match."""


class DriftError(TunnelsimError, ValueError):
    """Drift-correction input is unusable."""


class HelmertError(TunnelsimError, ValueError):
    """Helmert input is unusable (too few points, collinear, bad shapes or sigmas)."""


class CompareError(TunnelsimError, ValueError):
    """Inputs of a comparison are unusable."""


class PlanningError(TunnelsimError, ValueError):
    """Planning inputs are unusable."""


class StudyError(TunnelsimError, ValueError):
    """Study inputs are unusable."""


class TunnelsimCLIError(TunnelsimError, ValueError):
    """A command-line value is malformed."""


class PipelineError(TunnelsimError, ValueError):
    """A pipeline file is malformed or a step failed."""




class PreprocessError(TunnelsimError, ValueError):
    """Preprocessing input is unusable (empty cloud, bad parameter)."""


class ReconstructionError(TunnelsimError, ValueError):
    """A cloud cannot be reconstructed as a tunnel."""


class GazeboExportError(TunnelsimError, ValueError):
    """The export cannot be done as asked."""


class AlignmentError(TunnelsimError, ValueError):
    """An alignment definition is unusable (bad element, zero length, bad profile)."""


class DeformationError(TunnelsimError, ValueError):
    """A deformation definition is unusable."""


class FeatureError(TunnelsimError, ValueError):
    """A feature definition is unusable (outside the tunnel, overlapping, bad size)."""


class TunnelError(TunnelsimError, ValueError):
    """A tunnel cannot be generated from these parameters."""




class ProfileError(TunnelsimError, ValueError):
    """A cross-section profile is unusable (self-intersecting, degenerate, bad size)."""


__all__ = ["TunnelsimError", "AlignmentError", "ClusterError", "CompareError",
           "ControlPointError", "DeformationError", "DriftError", "FeatureError",
           "GazeboExportError", "HelmertError", "OdometryError", "PipelineError",
           "PlanningError",
           "PreprocessError", "ProfileError", "ReconstructionError", "StudyError",
           "TunnelError", "TunnelsimCLIError"]


class ClusterError(TunnelsimError, ValueError):
    """A cluster cannot be started or reached, or it lost a task for good."""


class OdometryError(TunnelsimError, ValueError):
    """LiDAR odometry cannot run: a missing backend, a drive too short, bad settings."""
