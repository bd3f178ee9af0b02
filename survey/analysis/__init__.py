"""Analysis: cloud-to-cloud and cloud-to-mesh distances, station planning, MLS studies,
trajectory errors (as evo computes them), and monitoring: sections against design,
rings, convergence and M3C2 between epochs."""

from __future__ import annotations

from typing import TYPE_CHECKING

from raytrace.lazy import lazy_exports_of

# The one list of public names (imported on first use; type checkers read it).
if TYPE_CHECKING:
    from .compare import Distances, ReferenceCloud, ReferenceMesh, cloud_to_cloud, cloud_to_mesh, distance_stats
    from .planning import Plan, Planner, RoutePlanner, Thresholds, axis_stations, lining_cells
    from .surface import RouteFrame, Surface, mesh_surface
    from .study import Study, StudyRow
    from .design import DesignProfile, read_design_profile
    from .sections import SectionCut, cut_cloud, cut_file, cut_mesh, section_chainages
    from .overbreak import Section, SectionReport, Volume, compare_sections
    from .rings import CircleFit, EllipseFit, RingFit, fit_circle, fit_ellipse, fit_rings
    from .convergence import Chords, RadialChange, chords, radial_change, sections_every
    from .m3c2 import M3C2, M3C2Params, M3C2Result, lod95, subsample, towards_axis
    from .developed import (DevelopedFrame, DevelopedGrid, DevelopedRaster, RasterAccumulator,
                            develop, develop_file, mesh_samples)
    from .clearance import (ClearanceResult, ViolationRegion, Violations, box_envelope,
                            clearance_file, read_envelope)   # not clearance(): see m3c2
    from .detectability import (DetectLayout, DetectRow, DetectTarget, Detectability, TargetScore,
                                ahat_a95, detection_limit, with_noise)
    from .trajectory import RelativeError, TrajectoryErrors, align_origin, path_pairs, trajectory_errors

__getattr__, __dir__, __all__ = lazy_exports_of(__name__, __file__, extra=())
