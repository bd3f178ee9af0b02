"""Analysis: cloud-to-cloud and cloud-to-mesh distances, station planning, MLS studies,
trajectory errors (as evo computes them), and monitoring: sections against design,
rings, convergence and M3C2 between epochs."""

from .compare import Distances, ReferenceCloud, ReferenceMesh, cloud_to_cloud, cloud_to_mesh, distance_stats
from .planning import Plan, Planner, RoutePlanner, Thresholds, axis_stations, lining_cells
from .surface import RouteFrame, Surface, mesh_surface
from .study import Study, StudyRow
from .design import DesignProfile, read_design_profile
from .sections import SectionCut, cut_cloud, cut_file, cut_mesh, section_chainages
from .overbreak import Section, SectionReport, Volume, compare_sections
from .rings import CircleFit, EllipseFit, RingFit, fit_circle, fit_ellipse, fit_rings
from .convergence import Chords, RadialChange, chords, radial_change, sections_every
# DECISION: the functions m3c2 and clearance are not imported here: each would hide
# its module (use survey.m3c2, survey.clearance or survey.analysis.m3c2.m3c2).
from .m3c2 import M3C2, M3C2Params, M3C2Result, lod95, subsample, towards_axis
from .developed import (DevelopedFrame, DevelopedGrid, DevelopedRaster, RasterAccumulator,
                        develop, develop_file, mesh_samples)
from .clearance import (ClearanceResult, ViolationRegion, Violations, box_envelope,
                        clearance_file, read_envelope)   # not clearance(): see m3c2
from .detectability import (DetectLayout, DetectRow, DetectTarget, Detectability, TargetScore,
                            ahat_a95, detection_limit, with_noise)
from .trajectory import RelativeError, TrajectoryErrors, align_origin, path_pairs, trajectory_errors

__all__ = ["Distances", "ReferenceCloud", "ReferenceMesh", "cloud_to_cloud",
           "cloud_to_mesh", "distance_stats", "Plan", "Planner", "RoutePlanner", "Thresholds",
           "RouteFrame", "Surface", "mesh_surface",
           "axis_stations", "lining_cells", "Study", "StudyRow", "RelativeError",
           "TrajectoryErrors", "align_origin", "path_pairs", "trajectory_errors",
           "DesignProfile", "read_design_profile", "SectionCut", "cut_cloud", "cut_file",
           "cut_mesh", "section_chainages", "Section", "SectionReport", "Volume",
           "compare_sections", "CircleFit", "EllipseFit", "RingFit", "fit_circle",
           "fit_ellipse", "fit_rings", "Chords", "RadialChange", "chords", "radial_change",
           "sections_every", "M3C2", "M3C2Params", "M3C2Result", "lod95", "subsample",
           "towards_axis",
           "DevelopedFrame", "DevelopedGrid", "DevelopedRaster", "RasterAccumulator",
           "develop", "develop_file", "mesh_samples", "ClearanceResult", "ViolationRegion",
           "Violations", "box_envelope", "clearance_file", "read_envelope",
           "DetectLayout", "DetectRow", "DetectTarget", "Detectability", "TargetScore",
           "ahat_a95", "detection_limit", "with_noise"]
