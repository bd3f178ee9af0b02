"""survey: the surveyor's workflow on top of ``sensors`` and ``raytrace``.

Sub-packages, lowest layer first (imports only point down)::

    world     alignments, profiles, features, deformation, the tunnel mesh and its files
    adjust    Helmert, control points, drift correction, simulated SLAM drift
    clouds    cloud I/O, filters, segmentation, axis and unrolling, reconstruction
    analysis  C2C/C2M comparison, station planning, MLS studies, trajectory errors,
              monitoring: sections, rings, M3C2, convergence, developed views
    report    Markdown/CSV reports and figures;  export: Gazebo
    cluster   running campaigns in-process or on a Dask cluster (optional extra)
    cli       the tunnelsim command (a leaf: nothing imports it)

Every public name is also available here (``from survey import fit_helmert``); they are
imported on first use, so ``import survey`` and ``tunnelsim --help`` stay fast.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from raytrace.lazy import lazy_exports_of

__version__ = "0.2.0"

SUBPACKAGES = ("world", "adjust", "clouds", "analysis", "report", "export", "cluster",
               "errors")

# The one list of public names: type checkers and IDEs import them here; the
# façade reads this block (raytrace.lazy.lazy_exports_of) and imports each on first use.
if TYPE_CHECKING:
    from survey.world.alignment import Alignment, Element, arc, clothoid, curve, straight
    from survey.world.profiles import Profile, arched_rectangle, circle, horseshoe
    from survey.world.features import Bolts, Cable, Drainage, Niche, Prisms, WetFloor
    from survey.world.deformation import Bulge, Convergence, Ovalisation
    from survey.world.mesh import (LABELS,
        REFLECTIVITY,
        TunnelMesh,
        read_axis,
        read_tunnel,
        write_ply,
        write_tunnel)
    from survey.world.generator import edge_length_for, make_tunnel
    from survey.world.presets import PRESETS, preset
    from survey.world.rock import RockRelief
    from survey.world.junction import Branch, branch_alignment, make_junction_tunnel
    from survey.adjust.helmert import HelmertResult, fit_helmert, from_parameters
    from survey.adjust.controlpoints import (ControlPoints, match, read_control_points,
        unmatched, unmatched_message)
    from survey.adjust.snooping import Snooping, SnoopStep, data_snooping
    from survey.adjust.odometry import OdometryResult, odometry_trajectory, run_odometry
    from survey.adjust.drift import DriftCorrection, fit_drift, leave_one_out
    from survey.adjust.slam import (slam_trajectory, to_slam_frame, DriftedRun,
        SlamObservation, observe_slam, observe_control)
    from sensors.io.cloudread import read_points, read_reference, cloud_bounds, iter_points
    from sensors.io.cloudmap import annotate_las, map_cloud, write_points_las
    from survey.clouds.preprocess import (VoxelGrid, radius_outliers, statistical_outliers,
        voxel_down_sample)
    from survey.clouds.axis import (
        LiningExtent,
        estimate_axis,
        extend_chainage,
        lining_extent,
        tunnel_frame,
        unroll,
        unroll_extended,
    )
    from survey.clouds.segment import CLASS_NAMES, TERRAIN, segment_tunnel
    from survey.clouds.reconstruct import (ReconstructedTunnel,
        poisson_tunnel,
        reconstruct_tunnel,
        reconstruct_within_budget)
    from survey.clouds.detail import attachment_tubes, DetailedMesh, with_detail_layer
    from survey.clouds.drives import (DriveFile, ScanFrame, frames_from_points, iter_frames,
        open_drive, replace_drive)
    from survey.analysis.compare import (Distances, ReferenceCloud, ReferenceMesh,
        cloud_to_cloud, cloud_to_mesh, distance_stats)
    from survey.analysis.planning import (Plan, Planner, RoutePlanner, Thresholds,
        axis_stations, lining_cells)
    from survey.analysis.surface import RouteFrame, Surface, mesh_surface
    from survey.analysis.study import Study, StudyRow
    from survey.analysis.trajectory import (RelativeError, TrajectoryErrors, align_origin,
        path_pairs, trajectory_errors)
    from survey.report.adjustment import drift_report, helmert_report
    from survey.report.compare import plot_histogram, stats_csv, stats_markdown
    from survey.report.planning import plan_csv, plan_markdown, plot_coverage, plan_summary
    from survey.report.study import plot_study, study_csv, study_markdown
    from survey.report.reconstruct import plot_support
    from survey.report.demo import demo_summary, summary_markdown, cloud_c2m_rms
    from survey.report.slam import plot_slam, slam_report
    from survey.analysis.design import DesignProfile, read_design_profile
    from survey.analysis.sections import (SectionCut, cut_cloud, cut_file, cut_mesh,
        section_chainages)
    from survey.analysis.overbreak import Section, SectionReport, Volume, compare_sections
    from survey.analysis.rings import (CircleFit, EllipseFit, RingFit, fit_circle,
        fit_ellipse, fit_rings)
    from survey.analysis.convergence import (Chords, RadialChange, chords, radial_change,
        sections_every)
    from survey.analysis.m3c2 import (M3C2, M3C2Params, M3C2Result, lod95, m3c2, subsample,
        towards_axis)
    from survey.report.sections import (plot_rings, plot_section, rings_csv, rings_markdown,
        sections_csv, sections_markdown, volumes_csv)
    from survey.analysis.developed import (DevelopedFrame,
        DevelopedGrid,
        DevelopedRaster,
        RasterAccumulator,
        develop,
        develop_file,
        mesh_samples)
    from survey.analysis.clearance import (ClearanceResult, ViolationRegion, Violations,
        box_envelope, clearance, clearance_file, read_envelope)
    from survey.report.developed import (clearance_markdown, plot_developed, regions_csv,
        violations_csv, write_developed)
    from survey.cluster import (Campaign, Station, open_executor, read_plan, scan_stations,
        simulate_windows)
    from survey.clouds.solid import (ScannerVoxelGrid, SolidMesh, nearest_scanner,
        reconstruct_solid)
    from survey.clouds.scanners import iter_scanned, read_positions, station_position
    from survey.analysis.detect_layout import DetectLayout, DetectTarget
    from survey.analysis.detectability import DetectRow, Detectability, TargetScore, with_noise
    from survey.analysis.detect_stats import ahat_a95, detection_limit
    from survey.report.detectability import (detect_csv, detect_markdown, detect_summary,
        plot_detectability, targets_csv)
    from survey.report.epochs import (chords_csv, convergence_markdown, m3c2_markdown,
        plot_m3c2_histogram, plot_radial, radial_csv)
    from survey.export.gazebo import export_gazebo
    from survey.export.gazebo_sdf import lidar_sdf
    from survey.errors import (TunnelsimError, AlignmentError, ClusterError, CompareError, ControlPointError, DeformationError, DriftError, FeatureError, GazeboExportError, HelmertError, OdometryError, PipelineError, PlanningError, PreprocessError, ProfileError, ReconstructionError, StudyError, TunnelError, TunnelsimCLIError)
    from sensors.io.errors import (FileFormatError, MeshFileError, PointFileError,
        TableFileError, TunnelFileError)

__getattr__, __dir__, __all__ = lazy_exports_of(__name__, __file__, modules=SUBPACKAGES)
