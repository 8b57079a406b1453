"""The project's one configuration: a YAML file mapped onto a typed, frozen, nested config.

Every field has its unit in its name and a description (printed as a comment by ``reloc config dump``). Defaults come
from the VoxelPlane-Reloc paper where it gives them. Loading reports every problem at once, each with its path
(``extraction.voxel_size_m: must be > 0, got -1``): unknown keys, wrong types, out-of-range values and duplicate YAML
keys. Nothing is silently corrected: types are strict (a string is never turned into a number).

Stage functions never take this object; factories and the CLI read it and pass plain parameters.
"""

from __future__ import annotations

import io
import re
import reprlib
from pathlib import Path
from typing import Annotated, Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, Strict, ValidationError, model_validator

__all__ = ["Config", "ConfigError", "YamlLoader", "load_config", "config_from_dict", "dump_config", "default_config",
           "load_yaml", "with_noise_law"]

# Sequences come from YAML lists; they are accepted as lists and stored as tuples (not a correction of a value).
FloatSeq = Annotated[tuple[float, ...], Strict(False)]
# Waits between retries: at least one (the last repeats), none negative.
BackoffSeq = Annotated[tuple[Annotated[float, Field(ge=0)], ...], Strict(False), Field(min_length=1)]
# No integer setting needs more; larger ones would overflow the int64 arithmetic of the numba kernels.
_MAX_INT = 2**31 - 1
# YAML nested deeper than this (or a tree of aliases that expands to more nodes) is not a config file.
_MAX_YAML_NODES = 100_000


class _Section(BaseModel):
    # NaN and infinity are not settings: every float has a finite range (a NaN would pass no check, an infinity
    # would only fail later, in the stage that uses it).
    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, validate_default=True, allow_inf_nan=False)

    @model_validator(mode="after")
    def _check_int_range(self) -> "_Section":
        bad = [f"{name}: must be at most {_MAX_INT} in magnitude, got {value}" for name, value in self
               if isinstance(value, int) and not isinstance(value, bool) and abs(value) > _MAX_INT]
        if bad:
            raise ValueError("\n".join(bad))
        return self


class CameraConfig(_Section):
    """The depth camera, how it is mounted and where gravity comes from."""

    min_depth_m: float = Field(0.3, gt=0, description="Nearer depths are dropped as invalid.")
    max_depth_m: float = Field(8.0, gt=0, description="Farther depths are dropped (noise grows with depth^2).")
    pixel_stride: int = Field(1, ge=1, le=16, description="Use every n-th pixel in both directions.")
    gravity_source: Literal["imu", "mounting", "camera_y"] = Field(
        "camera_y",
        description="Where the gravity direction of a frame without its own (an IMU's) comes from: nowhere (imu), "
        "the mounting T_base_cam on a level base (mounting), or the camera's +y axis (y down) within max_tilt_deg "
        "as in the paper (camera_y).",
    )
    max_tilt_deg: float = Field(
        20.0, ge=0, le=90, description="Tilt tolerance of the camera when gravity is taken from its y axis (the "
        "paper's allowance in tau_g): widens matching.ground_tolerance_deg for such plane sets."
    )
    T_base_cam: FloatSeq = Field(
        (0.0, 0.0, 1.0, 0.2, -1.0, 0.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.5, 0.0, 0.0, 0.0, 1.0),
        description="Camera mounting on the robot base, 16 numbers row-major (p_base = T_base_cam @ p_cam). "
        "Default: optical axis forward along base x, 0.2 m ahead and 0.5 m above the base origin.",
    )

    @model_validator(mode="after")
    def _check(self) -> "CameraConfig":
        errors = []
        if self.max_depth_m <= self.min_depth_m:
            errors.append(f"max_depth_m: must be > min_depth_m ({self.min_depth_m}), got {self.max_depth_m}")
        if len(self.T_base_cam) != 16:
            errors.append(f"T_base_cam: expected 16 numbers (4x4 row-major), got {len(self.T_base_cam)}")
        else:
            import numpy as np

            from reloc.transforms import check_transform

            try:
                check_transform(np.array(self.T_base_cam).reshape(4, 4), "T_base_cam")
            except ValueError as exc:
                errors.append(str(exc))
        if errors:
            raise ValueError("\n".join(errors))
        return self


class ExtractionConfig(_Section):
    """Voxel plane extraction (paper: 'Voxelplane extraction', Eq. 1-3)."""

    voxel_size_m: float = Field(0.25, gt=0, le=5.0, description="Edge n of the n x n x n voxel grid.")
    min_points_per_voxel: int = Field(12, ge=3, description="Voxels with fewer points hold no plane.")
    max_thickness_sigmas: float = Field(
        4.0, gt=0, description="Planarity: RMS distance to the voxel plane must be below this many sensor sigmas."
    )
    max_thickness_floor_m: float = Field(0.01, ge=0, description="Lower bound of the thickness threshold.")
    max_eigen_ratio: float = Field(
        0.05, gt=0, le=1,
        description="Planarity: (smallest eigenvalue - noise variance) / middle eigenvalue of the voxel scatter below this.",
    )
    max_normal_std_deg: float = Field(
        5.0, gt=0, le=90, description="Planarity: angular standard deviation of the voxel normal below this."
    )
    min_inlier_fraction: float = Field(
        0.7, gt=0, le=1, description="Planarity after the robust refit: the points' Tukey weights sum to at least this "
        "share of the voxel's points (a weighted inlier share: a clean voxel of Gaussian noise scores about 0.8)."
    )
    voxel_fit_max_points: int = Field(
        256, ge=3, description="Voxels with more points are refit from an even subsample (weights scaled up)."
    )
    adaptive_weights: bool = Field(
        True,
        description="Eq. 2-3 position weights in the per-voxel refit (off = the paper's VR-NE). On: on whole frames "
        "they lower the tail errors (benchmarks/extraction_accuracy.py protocol 2); on single planes (protocol 1) "
        "they do not help.",
    )
    alpha: float = Field(
        0.5, ge=0, description="Eq. 2: slope of the square model 1 - alpha (r/r_max)^2 inside sigma (r normalised)."
    )
    beta: float = Field(2.0, ge=0, description="Eq. 2: decay of exp(-beta (r/r_max)^2) outside sigma (r normalised).")
    noise_weights: bool = Field(True, description="Also weight each point by 1 / sigma_z(z)^2 of the sensor model.")
    noise_direction: Literal["ray", "normal"] = Field(
        "ray",
        description="Depth noise moves points along their viewing ray (depth cameras; planes solved in the unbiased "
        "ray form a . p = 1) or along the plane normal (the paper's synthetic Table 2 protocol).",
    )
    irls_iterations: int = Field(3, ge=0, le=50, description="Residual-based robust reweighting passes (0 = off).")
    irls_kernel_sigmas: float = Field(3.0, gt=0, description="Robust kernel width in units of the sensor sigma.")
    flying_pixel_sigmas: float = Field(
        0.0, ge=0,
        description="Drop every pixel beside a depth jump of more than this many noise sigmas (and 3% of the depth): "
        "flying pixels between two surfaces, which real sensors report at occluding edges, and both sides of the "
        "edge. 0 = off (the default; measured in docs/BENCHMARKS.md, 'Flying pixels').",
    )
    noise_model: Literal["kinect", "tof", "stereo", "constant"] = Field(
        "kinect", description="Sensor noise law used by the weights and the thresholds."
    )
    noise_coeff: float = Field(
        1.425e-3, gt=0, description="kinect: sigma = c z^2; tof: sigma = c z; stereo: sigma = c z^2; constant: c."
    )
    area_patch_m: float = Field(0.1, gt=0, description="Patch edge l for the area estimate (paper, constraint 3).")
    sample_spacing_m: float = Field(0.1, gt=0, description="Spacing of each plane's point sample (projection, overlap).")
    inlier_sigmas: float = Field(
        4.0, gt=0, description="A point supports a plane within this many noise sigmas (times the plane's scale)."
    )
    refine_boundary: bool = Field(
        True, description="Points of neighbouring voxels (corners, edges, sparse voxels) may support a plane too."
    )
    refine_iterations: int = Field(
        2, ge=0, le=10,
        description="Robust passes over the points near each merged plane: refit, then fragments merge again "
        "(0 = planes straight from the merged voxel moments).",
    )
    corner_min_angle_deg: float = Field(
        20.0, gt=0, le=90,
        description="The refinement's corner test: another candidate plane at least this far off in angle, met by a "
        "point's pixel ray near where its own plane is, makes the point a corner point (left out of the refit; a "
        "plane made mostly of them is a bevel). Closer candidates are pieces of one surface. 10 drops the strips "
        "tilted 13-18 deg across a step between parallel surfaces (a door in a niche) and gives cleaner planes, but "
        "cost relocalization (docs/BENCHMARKS.md, 'A door in a niche').",
    )
    bevel_max_width_voxels: float | None = Field(
        None, gt=0,
        description="A plane made mostly of corner points is dropped as a bevel across the corner; with a number, "
        "only when at most this many voxels wide across its shorter in-plane axis (a bevel is a strip along the "
        "corner; a far stereo wall whose wide noise band makes most of its points corner points is not). Null: any "
        "width (the default; see docs/BENCHMARKS.md).",
    )
    min_plane_points: int = Field(200, ge=3, description="Merged planes with fewer points are dropped.")
    min_plane_area_m2: float = Field(0.04, ge=0, description="Merged planes smaller than this are dropped.")


class MergingConfig(_Section):
    """Plane merging by 26-neighbour voxel growth, then merging of under-grown fragments (paper: 'Plane merging')."""

    enabled: bool = Field(True, description="Off = the paper's VR-NM (every voxel plane stays separate).")
    grow_max_angle_deg: float = Field(10.0, gt=0, le=90, description="Growth: normals of neighbours within this angle.")
    grow_max_offset_m: float = Field(
        0.02, gt=0, description="Growth: the neighbour's centroid within this distance of the growing plane..."
    )
    grow_offset_sigmas: float = Field(
        2.0, ge=0, description="...or within this many depth sigmas of it, when more (a voxel face moves a centroid)."
    )
    grow_angle_noise_sigmas: float = Field(
        2.0, ge=0,
        description="Growth and fragments: the angle tolerance is at least atan(this * sigma_z / voxel plane spread).",
    )
    undergrown_max_angle_deg: float = Field(8.0, gt=0, le=90, description="Fragments: normals within this angle.")
    undergrown_max_depth_angle_deg: float = Field(
        5.0, gt=0, le=90,
        description="Fragments: the centroid-to-centroid vector within this angle of perpendicular to the normal.",
    )
    undergrown_max_offset_m: float = Field(0.05, gt=0, description="Fragments: centroid off the other plane by at most this.")
    undergrown_radius_scale: float = Field(
        2.0, gt=0,
        description="Fragments: centroids within the larger plane's radius times this factor (2: the two halves of "
        "a wall cut by a door are ~1.6 radii apart).",
    )
    layer_min_shared: float | None = Field(
        None, ge=0, le=1,
        description="Layers: two planes within the fragments' angle, within the planarity thickness of each other and "
        "sharing at least this fraction of the smaller one's 2x2 pixel blocks are one surface (stereo's disparity "
        "steps cut a far wall into parallel layers seen through the same rays) and become one plane. 0 = never; "
        "null (the default) = by the sensor: 0.5 with a stereo camera's noise law, never with any other (see "
        "docs/BENCHMARKS.md).",
    )


class MappingConfig(_Section):
    """Building a global plane map from a posed sequence, and submaps from a window of frames."""

    keyframe_min_translation_m: float = Field(0.2, ge=0, description="A new keyframe after moving this far...")
    keyframe_min_rotation_deg: float = Field(10.0, ge=0, description="...or after turning this much.")
    fuse_max_angle_deg: float = Field(8.0, gt=0, le=90, description="Association: normals within this angle.")
    fuse_max_offset_m: float = Field(
        0.03, gt=0, description="Association: the new plane's samples within this distance of the plane (median)."
    )
    fuse_min_overlap: float = Field(
        0.0, ge=0, le=1, description="Association: samples closer than sample spacing, as a fraction (0 = spheres touch)."
    )
    fuse_check_bridged: bool = Field(
        True, description="A plane associated with several fused planes goes to the one it fits best, and the others "
        "join it only if they agree with it (normals within the angle, each one's samples within the offset of the other, "
        "in the median): a plane that touches two surfaces does not make them one. false = merge them all (before "
        "2026-11-26).",
    )
    fuse_max_far_fraction: float = Field(
        0.25, ge=0, le=1, description="Association: at most this share of a plane's samples more than twice "
        "fuse_max_offset_m from the fused plane (a plane mostly on a surface and partly on one behind it passes the "
        "median test, not this one). 1 = off (before 2026-11-27).",
    )
    fuse_check_local: bool = Field(
        False, description="Association: the fused plane's own samples around the new plane also within "
        "fuse_max_offset_m of the new plane (median), not only the new plane's samples near the fused plane (a door "
        "in its niche joined a wall whose fused plane had turned a little). Off by default: on the suite's maps it "
        "left fewer bent planes, and relocalization answered more views with more false positives (2026-11-30).",
    )
    map_sample_spacing_m: float = Field(0.1, gt=0, description="Voxel size of each map plane's point sample.")
    min_observations: int = Field(
        3, ge=1, description="Map planes seen in fewer keyframes are dropped (mostly facets of curved clutter)."
    )
    submap_window_frames: int = Field(1, ge=1, description="K: frames fused into a submap with their relative poses.")
    submap_max_window_frames: int = Field(
        0, ge=0, description="When the submap of K frames cannot pin a pose (the submap_grow_* tests below), the "
        "window grows back in time, K/2 frames at a time, up to this many frames (0 = the window stays at K). A view "
        "along a corridor cannot tell where along it it is; the frames before, which saw the door it passed, can.",
    )
    submap_grow_min_planes: int = Field(
        6, ge=0, description="Grow: the submap has fewer planes of at least submap_grow_min_area_m2 than this..."
    )
    submap_grow_min_support_m2: float = Field(
        1.0, ge=0, description="...or less area of them along the weakest direction of the translation they fix "
        "(normals within 60 deg of it).",
    )
    submap_grow_min_area_m2: float = Field(
        0.5, ge=0, description="Planes at least this large count in those tests (faces of 0.3-0.4 m^2, which the map "
        "often lacks, stopped windows growing at 0.3).",
    )

    @model_validator(mode="after")
    def _check_window(self) -> "MappingConfig":
        if 0 < self.submap_max_window_frames < self.submap_window_frames:
            raise ValueError("submap_max_window_frames: expected 0 (the window does not grow) or at least "
                             f"submap_window_frames ({self.submap_window_frames}), got "
                             f"{self.submap_max_window_frames}")
        return self
    free_space_voxel_m: float = Field(
        0.15, ge=0, description="Voxel edge of the map's known free space carved along depth rays (0 = none)."
    )
    free_space_margin_m: float = Field(
        0.3, ge=0, description="Rays stop carving this far before their surface (noise, grazing angles)."
    )
    free_space_pixel_stride: int = Field(8, ge=1, description="Carve along every n-th pixel's ray in both directions.")
    free_space_max_range_m: float = Field(5.0, gt=0, description="Rays to farther surfaces carve nothing.")
    submap_min_observations: int = Field(
        2, ge=1, description="In submaps of 3+ frames, planes seen in fewer frames are dropped."
    )
    submap_check_sigmas: float = Field(
        4.0, ge=0, description="A window's older frame is left out of the submap when its planes, moved with "
        "odometry, disagree with the newest frame's view of the same surfaces by more than this many sigmas of the "
        "two fits (and the minima below): its odometry pose is off. 0 = no check.",
    )
    submap_check_min_angle_deg: float = Field(1.0, ge=0, description="...and by at least this angle...")
    submap_check_min_offset_m: float = Field(0.02, ge=0, description="...or this offset at its centroid.")
    submap_check_min_area_m2: float = Field(
        0.3, ge=0, description="Only planes at least this large take part in the odometry check."
    )
    submap_check_fraction: float = Field(
        0.34, ge=0, le=1, description="The frame is left out when its disagreeing planes weigh (square root of area) "
        "at least this fraction of the planes it shares with the newest frame.",
    )


class MatchingConfig(_Section):
    """Triplet selection and transform per triplet (paper: 'Plane matching')."""

    incremental: bool = Field(True, description="Incremental input of submap planes (off = the paper's VR-NI).")
    initial_planes: int = Field(5, ge=3, description="Planes fed first by the incremental input (paper: 5).")
    structural_constraints: bool = Field(
        True, description="Ground, orthogonality, distance and area constraints (off = the paper's VR-NG)."
    )
    ground_tolerance_deg: float = Field(
        15.0, gt=0, le=90, description="tau_g: a floor normal within this angle of the up direction (Eq. 4-5)."
    )
    triplet_min_angle_deg: float = Field(40.0, ge=0, le=90, description="Orthogonality window, low end (paper: 40).")
    triplet_max_angle_deg: float = Field(140.0, ge=90, le=180, description="Orthogonality window, high end (paper: 140).")
    pair_angle_tolerance_deg: float = Field(
        6.0, gt=0, description="Angles inside a map triplet must equal those of the submap triplet within this."
    )
    max_sphere_gap_m: float = Field(
        3.0, ge=0,
        description="Map planes of a triplet: their spheres (centroid, radius) at most this far apart (the index keeps "
        "such pairs). Per query the bound is tighter: what the submap saw of the two planes, plus gap_tolerance_m.",
    )
    gap_tolerance_m: float = Field(
        0.2, ge=0, description="Added to the submap's own distance between two planes to bound the map planes' gap."
    )
    extent_tolerance_m: float = Field(
        0.3, ge=0,
        description="Where a submap plane lies relative to another of its triplet (signed distances of its samples "
        "to the other plane) must lie within the map's extents for the pair, give or take this.",
    )
    extent_trim_fraction: float = Field(
        0.01, ge=0, lt=0.5,
        description="...leaving out this fraction of a submap plane's samples at either end of each range (a few "
        "stray samples, such as a wall's corner points on the floor, would otherwise stretch it; 0 = every sample).",
    )
    min_area_ratio: float = Field(
        0.5, gt=0, le=1, description="Map plane area must be at least this times the submap plane area."
    )
    max_condition_number: float = Field(
        50.0, gt=1, description="Reject triplets whose translation system is worse conditioned than this."
    )
    max_submap_planes: int = Field(30, ge=3, description="Largest planes of a submap considered at all.")
    far_overlay_sigma_m: float = Field(
        0.06, ge=0,
        description="A submap plane where the sensor's depth noise (extraction's law) reaches this, lying over a "
        "larger submap plane 3-25 deg off it, is left out: a fit across several surfaces (0 = never).",
    )
    sparse_overlay_sigma_m: float = Field(
        0.015, ge=0,
        description="A noisy sensor's plane laid over a larger one as above, from where the noise reaches this, "
        "and sparse (below), a fit that few of the window's frames made, does not keep a pose from explaining enough "
        "by its conflicts with the map (0 = never).",
    )
    sparse_overlay_max_density: float = Field(
        0.1, ge=0, le=1,
        description="Sparse: at most this share of the larger plane's points per m^2 (0 = never).",
    )
    degenerate_min_angle_deg: float = Field(
        15.0, gt=0, le=60,
        description="Normals closer than this (or than 180 minus this) make a triplet degenerate (always checked).",
    )
    min_triple_product: float = Field(
        0.2, ge=0, le=1,
        description="|n0 . (n1 x n2)| of a triplet's normals at least this: they must span 3-D space (translation).",
    )
    max_candidates: int = Field(
        400_000, ge=1000, description="Map triplets kept per round at most (more are cut and counted as truncated)."
    )


class EvaluationConfig(_Section):
    """Evaluation of each triplet's transform and the final choice (Eq. 10-14)."""

    projection: bool = Field(True, description="Map-plane projection inliers, Eq. 10 (off = VR-NP).")
    projection_inlier_m: float = Field(0.08, gt=0, description="A projected sample is an inlier within this distance.")
    min_projection_ratio: float = Field(0.5, ge=0, le=1, description="Pairs below this inlier fraction do not match.")
    noisy_min_projection_ratio: float = Field(
        0.3, ge=0, le=1,
        description="min_projection_ratio for a sensor whose depth noise at 3 m is above noisy_sensor_sigma_m (never "
        "raised): far planes of a noisy sensor come out tilted by more than projection_inlier_m across their extent, "
        "so fewer of their samples project within it at the true pose (the suite's stereo: 5 % of true pairs under "
        "half, Kinect and ToF none).",
    )
    noisy_sensor_sigma_m: float = Field(
        0.02, ge=0,
        description="Depth noise at 3 m (extraction's noise law) above which noisy_min_projection_ratio applies "
        "(Kinect 1.3 cm and ToF 0.9 cm class sensors keep min_projection_ratio).",
    )
    overlap: bool = Field(True, description="Plane overlap by centre and radius, Eq. 11 (off = VR-NO).")
    min_overlap: float = Field(
        0.7, ge=0, le=1,
        description="Pairs below this overlap do not match: the fraction of the submap plane's samples falling within "
        "the map plane's extent (its samples on a grid of extent_cell_m).",
    )
    extent_cell_m: float = Field(0.25, gt=0, description="Grid of the map's spatial hash (overlap, Eq. 11).")
    verify_samples_per_plane: int = Field(
        12, ge=1, le=256, description="Samples per submap plane (farthest-point) used to verify a transform."
    )
    min_explained_fraction: float = Field(
        0.85, ge=0, le=1,
        description="A pose must explain this fraction of the submap, each plane weighing sqrt(area): unexplained "
        "large planes and furniture count against it.",
    )
    well_matched_planes: int = Field(
        0, ge=0,
        description="A pose matching this many planes or more needs to explain only well_matched_explained_fraction "
        "of the submap (0: no such exception). For a sensor noisier than noisy_sensor_sigma_m, "
        "noisy_well_matched_planes applies instead.",
    )
    well_matched_explained_fraction: float = Field(
        0.85, ge=0, le=1, description="The fraction a pose matching well_matched_planes planes must explain.",
    )
    noisy_well_matched_planes: int = Field(
        8, ge=0,
        description="well_matched_planes for a sensor whose depth noise at 3 m is above noisy_sensor_sigma_m: its far "
        "planes come out tilted off their map planes and stay unexplained at the true pose (four stereo suites: 47 "
        "true poses matching 8-19 planes explained 0.75-0.85), while the false positives that 0.75 or 0.8 for every "
        "pose let in matched 5 or 6 planes. 0 turns it off. Not for a less noisy sensor: with ToF noise a meeting-room "
        "view was answered in the next room with 14 planes matched and 0.78 explained.",
    )
    noisy_well_matched_explained_fraction: float = Field(
        0.75, ge=0, le=1,
        description="well_matched_explained_fraction for a sensor whose depth noise at 3 m is above "
        "noisy_sensor_sigma_m.",
    )
    min_explained_known_fraction: float = Field(
        0.7, ge=0, le=1,
        description="A pose explaining at least this fraction may also win when the rest of its submap lands only where "
        "the map knows nothing (no plane in conflict with a map surface) and makes up min_explained_fraction: a place "
        "the mapping run saw in part. 0 turns this off.",
    )
    known_conflict_min_area_m2: float = Field(
        0.5, ge=0,
        description="...where only planes of at least this area count as in conflict: a facet of curved clutter a few "
        "centimetres off a map surface does not decide (0: every plane counts, as before 2026-11-30; over the tuned "
        "suite and eight held-out replicates 11 true poses more and no false positive, 1.0 added two).",
    )
    facet_max_area_m2: float = Field(
        1.0, ge=0,
        description="A facet of curved clutter under this area (a plane that touches another one 8-60 deg away, the "
        "two bending away from each other: a plant pot, a chair's back) in conflict with the map is left out when "
        "judging whether a pose explains enough of the submap: extraction cuts a curved surface into facets that "
        "follow the viewpoint, so the map holds other facets of it. Rivals are judged as before. 0 turns this off.",
    )
    far_conflict_min_planes: int = Field(
        6, ge=0,
        description="A noisy sensor's planes where its noise reaches matching.far_overlay_sigma_m (5 m for an OAK-D "
        "class stereo camera), in conflict with the map, are left out in the same way for a pose that matches this "
        "many planes or more: one more than scene uniqueness needs, as the far planes that told a half-turned twin "
        "apart are no longer held against it (0 = never).",
    )
    refine_iterations: int = Field(2, ge=0, le=10, description="Least-squares refinements of the winning pose.")
    refine_at_centroids: bool = Field(
        True,
        description="The refinement's translation fits each matched plane where the submap saw it (its centroid on "
        "the map plane); off = Eq. 7's offsets, compared at the submap frame's origin (the latest camera), where a "
        "normal a degree off its map plane moves the pose by its lever arm (17 cm for a plane 10 m from it).",
    )
    refine_max_angle_deg: float = Field(
        2.0, gt=0, description="Refinement drops matched pairs whose normals disagree by more than this..."
    )
    refine_max_offset_m: float = Field(0.04, gt=0, description="...or whose centroid is farther than this off the plane.")
    noisy_refine_max_angle_deg: float = Field(
        4.0, gt=0,
        description="refine_max_angle_deg for a sensor whose depth noise at 3 m is above noisy_sensor_sigma_m (never "
        "lowered): the stereo camera's small faces come out 2-4 deg off their map planes, and a true pose whose "
        "faces across the view were all dropped had no least-squares pose (the suite's stereo: +4, +4 and +1 true "
        "poses on the tuned suite and replicates A and B, no false positive; Kinect and ToF keep 2 deg).",
    )
    refine_fallback_max_angle_deg: float = Field(
        3.0, ge=0,
        description="When the pairs within refine_max_angle_deg do not fix the pose, the refinement keeps those within "
        "this angle instead (0, or at most that angle: off). A curved object's facets come out a few degrees off the "
        "map planes they lie on, and a true pose held along one axis only by them had no least-squares pose "
        "(2026-11-29: +1 and +2 true poses on the held-out replicates A and B with Kinect noise and +1 on B with ToF, "
        "none lost and no false positive added; 4 deg lost three true poses, two of them to rivals it refined).",
    )
    final_max_angle_deg: float = Field(
        5.0, gt=0,
        description="The refined pose is verified again with matches within this angle (tighter than "
        "match_max_angle_deg rejects look-alikes, but also true poses from noisy sensors)...",
    )
    final_max_offset_m: float = Field(0.08, gt=0, description="...and this offset.")
    covariance_inflation: float = Field(
        4.0, gt=0,
        description="A relocalized pose's covariance (from its matched planes, scaled by their residuals) is "
        "multiplied by this, so that the simulated suite's pose errors follow it (docs/BENCHMARKS.md, 'Pose "
        "covariance').",
    )
    min_competitor_fraction: float = Field(
        0.6, ge=0, le=1,
        description="Poses explaining at least this fraction compete in the decision (ambiguity test) even though only "
        "one explaining min_explained_fraction can win: a true pose the map covers badly still blocks a twin.",
    )
    min_counted_area_m2: float = Field(
        0.3, ge=0,
        description="Submap planes smaller than this count toward the explained fraction only when matched (small "
        "planes are mostly facets of curved clutter that no map holds).",
    )
    free_space: bool = Field(
        True, description="Reject poses that put a submap plane where the map saw empty space (maps built from depth)."
    )
    max_free_fraction: float = Field(
        0.5, ge=0, le=1,
        description="An unmatched submap plane (>= min_counted_area_m2) with more of its samples than this in the "
        "map's known free space contradicts the pose.",
    )
    free_far_min_fraction: float = Field(
        0.25, ge=0, le=1,
        description="Free space stops short of every map surface, so a plane put across a narrow place (a wall "
        "across a corridor) has most samples near a surface and never free: when at least this fraction of its "
        "samples are away from every map surface, more than max_free_fraction of those in free space contradicts "
        "the pose too (0 = off).",
    )
    occlusion: bool = Field(
        True,
        description="In the decision, a submap plane unknown to the map under a pose but hidden behind a map surface "
        "from every camera of the submap's window (a look-alike pose puts what was seen through a doorway behind a "
        "wall) counts against the pose, as a plane in conflict with the map does.",
    )
    occlusion_margin_m: float = Field(
        0.04, gt=0, description="A point is hidden by a map surface it lies more than this behind."
    )
    occlusion_erode_m: float = Field(
        0.3, ge=0,
        description="...crossed where the map plane has surface at least this far all around (map planes reach a few "
        "tenths of a metre past their edges: a door-sized opening must stay open).",
    )
    occlusion_min_fraction: float = Field(
        0.5, gt=0, le=1, description="A plane is hidden when at least this fraction of its samples are."
    )
    occlusion_max_sensor_sigma_m: float = Field(
        0.02, ge=0,
        description="The occlusion test is off for a sensor whose depth noise at 3 m (extraction's noise law) is "
        "above this: its maps close doorways (far points seen along a wall land on it), and true poses seen through "
        "them lost to look-alikes (the suite's stereo, 7.3 cm). Kinect (1.3 cm) and ToF (0.9 cm) class sensors keep "
        "it.",
    )
    occlusion_from_behind: bool = Field(
        True,
        description="Map surfaces hide from behind too: a line of sight from a camera more than occlusion_erode_m "
        "behind a map plane (on the side its mapping cameras never saw) to a point more than occlusion_margin_m in "
        "front of it is blocked where the plane has surface all around the crossing. A look-alike pose that puts "
        "the cameras outside a room sees through its walls from their backs. Only with a map that knows its free "
        "space (built maps do).",
    )
    path_test: bool = Field(
        True,
        description="In the decision over refined poses, a pose under which the submap's camera path (its window's "
        "cameras, in order) walks through a wall of the map is no rival (it may still win: a wall the map draws "
        "across a doorway must not turn the true pose away). Off, as occlusion is, for a sensor noisier than "
        "occlusion_max_sensor_sigma_m (its maps close doorways).",
    )
    path_min_step_m: float = Field(
        0.3, gt=0, description="The camera path is walked in steps of at least this length."
    )
    path_margin_m: float = Field(
        0.05, gt=0, description="A step goes through a wall when its ends are more than this on either side of it."
    )
    path_reach_m: float = Field(
        0.5, ge=0,
        description="...crossed where the wall has surface, and surface on along its horizontal every 0.1 m up to "
        "this far on both sides (a doorway the map saw narrowed by its edges still leaves a gap within reach).",
    )
    scene_uniqueness: bool = Field(True, description="Require tau_m matched planes (off = VR-NS).")
    min_matched_planes: int = Field(5, ge=3, description="tau_m: matched planes a pose needs (paper: 5).")
    min_direction_support_m2: float = Field(
        0.4, ge=0,
        description="Matched planes along the translation's weakest direction must add up to this area: no small "
        "plane alone may pin the pose along an axis (part of scene uniqueness).",
    )
    weak_slide_range_m: float = Field(
        8.0, ge=0,
        description="A pose short of that support is still accepted when it is the only peak along its weakest "
        "direction: every copy slid 0.5 m or more along it, up to this far, fails verification or matches at least "
        "2 planes fewer (the extents of walls, door niches and furniture pin it; 0 = off).",
    )
    hidden_against_support: bool = Field(
        True,
        description="Planes the pose puts where the map says its cameras could not see them (behind the map's "
        "surfaces; the occlusion test) take their area off that support along the weakest direction: a meeting room "
        "seen through a doorway, placed in a corridor pinned by one cabinet face, is not a pose.",
    )
    conflicts_against_support: bool = Field(
        True,
        description="Planes in conflict with the map at the pose (off a map surface facing the same way) take their "
        "area off that support along the weakest direction too: a stereo corridor view was placed 0.30 m along "
        "the corridor by a 2.3 m^2 face while a 6.25 m^2 wall facing the same way lay off its map wall.",
    )
    max_conflict_area_m2: float = Field(
        1.0, ge=0,
        description="A pose under which a submap plane of this area or more lies off a map surface facing the same "
        "way (in conflict with the map) is rejected, however much else it matches (0 = off; off for a sensor noisier "
        "than occlusion_max_sensor_sigma_m).",
    )
    conflict_vetoes_rivals: bool = Field(
        True,
        description="A rival pose with such a plane in conflict (that test would turn it away if it won) or hidden "
        "behind a map surface, explaining less than min_explained_fraction of the submap, is no rival.",
    )
    min_uncontradicted_planes: int = Field(
        5, ge=0,
        description="Scene uniqueness counted net of the map's contradictions: the winning pose's matched planes "
        "less its planes in conflict with the map (off a map surface facing the same way, or hidden behind one) must "
        "be at least this (0 = off; for a sensor noisier than occlusion_max_sensor_sigma_m, "
        "noisy_min_uncontradicted_planes applies instead). A pose whose five matches are undone by two contradictions "
        "has the evidence of three.",
    )
    noisy_min_uncontradicted_planes: int = Field(
        4, ge=0,
        description="min_uncontradicted_planes for a sensor noisier than occlusion_max_sensor_sigma_m, where only the "
        "conflicts not forgiven already count against the pose (forgiven: far planes from where the noise reaches "
        "far_overlay_sigma_m, facets of curved clutter, sparse planes laid over larger ones). 0 = off.",
    )
    match_max_angle_deg: float = Field(5.0, gt=0, description="A submap plane matches a map plane within this angle...")
    match_max_offset_m: float = Field(0.08, gt=0, description="...and this offset, after the transform.")
    kde_sigma_translation_m: float = Field(0.1, gt=0, description="Eq. 14 information matrix: translation scale.")
    kde_sigma_rotation_deg: float = Field(3.0, gt=0, description="Eq. 14 information matrix: rotation scale.")
    min_score: float = Field(0.0, ge=0, description="The best mode's density must be above this to be accepted.")
    probe_twins: bool = Field(
        True,
        description="Before accepting, search the winner's triplets again with only angle, handedness and ground "
        "tests, so that twins the map covers less completely still compete (and make the query ambiguous).",
    )
    probe_planes: int = Field(
        3, ge=0,
        description="The twin probe also tries the triplets among this many of the winner's largest matched planes "
        "(0: only the winner's own triplet), so a twin whose map lacks one plane of that triplet is still found "
        "(more planes try more triplets: more time, and on the simulated suite 5 planes lowered recall).",
    )
    probe_extent_tolerance_m: float = Field(
        3.0, gt=0,
        description="The twin probe frees the area and sphere-gap filters but keeps the signed-extent filter within "
        "this tolerance (free, a 2,000-plane map gave 88,000 candidates and 0.3 s per probe; 3 m keeps every twin "
        "of the suite).",
    )
    tight_decision: bool = Field(
        True,
        description="Decide between poses after refining every mode over its matched planes and verifying it at "
        "the final tolerances: a look-alike that matches only within the loose search tolerances loses those "
        "planes, the true pose keeps them.",
    )
    decision_max_offset_m: float = Field(
        0.03, gt=0,
        description="With tight_decision, a plane counts as evidence for a refined pose when it lies within this "
        "offset of its map plane (acceptance itself uses final_max_offset_m).",
    )
    decision_modes: int = Field(
        6, ge=1,
        description="With tight_decision, how many modes (the best by matched planes and explained fraction) are "
        "refined and decided over: poses beyond them match few planes, only dilute the frequency weights (Eq. "
        "12-13) and cost time (an apartment query can have 47).",
    )
    decision_conflict_m: float = Field(
        0.05, ge=0,
        description="With tight_decision, an unmatched plane conflicts with a map surface facing the same way when "
        "it lies farther than this from it (between decision_max_offset_m and this it is neither matched nor in "
        "conflict).",
    )
    near_decision_offsets: bool = Field(
        True,
        description="Where the decision offsets are raised to follow a noisy sensor (DECISION_SIGMAS and "
        "CONFLICT_SIGMAS times its noise at 3 m), each submap plane of near_decision_min_area_m2 or more nearer "
        "than 3 m to the nearest camera of its window gets the offsets of the noise at that distance, never below "
        "decision_max_offset_m and decision_conflict_m: a stereo plane seen from 2 m is measured to 1 cm, and a "
        "rival that puts it 6 cm off a map surface facing its way contradicts the map there. On by default since "
        "conflicts_against_support: over nine stereo suites the two answer 23 views more and add no false positive "
        "(docs/BENCHMARKS.md, 'Planes in conflict against the weakest direction's support').",
    )
    near_decision_min_area_m2: float = Field(
        0.5, ge=0.0,
        description="With near_decision_offsets, planes smaller than this keep the offsets of 3 m: a small plane's "
        "offset, and the map's small planes (facets of furniture), are less sure than the noise at its distance "
        "says; at 0 a twin-room view and a symmetric-room view, labelled ambiguous, were answered because a "
        "rival or the truth lost a plane of 0.47 or 0.35 m^2 to a conflict.",
    )
    optimistic_rivals: bool = Field(
        True,
        description="In the ambiguity test a rival pose's planes that land where the map knows nothing count as if "
        "they matched: an incomplete map must not make a twin look worse than the pose it covers well.",
    )
    unrefined_rivals: bool = Field(
        True,
        description="With tight_decision, a mode with no least-squares pose (its planes disagree by more than the "
        "refinement tolerances) is not decided on at its raw pose: when it matched about as well as the winner, "
        "the query is rejected as ambiguous.",
    )
    unrefined_rival_margin: float = Field(
        0.5, ge=0,
        description="With unrefined_rivals, how much less (matched planes plus explained fraction, as raw "
        "hypotheses) such a mode may have matched than the winner and still make the query ambiguous.",
    )
    equal_rivals: bool = Field(
        True,
        description="With tight_decision, a winner over refined poses is rejected as ambiguous when another refined "
        "pose, distinct from it, has as much evidence (matched planes less planes in conflict, plus the explained "
        "fraction), however the density ranks them: the four quarter turns of a square room.",
    )
    equal_rival_margin: float = Field(
        0.5, ge=0, description="With equal_rivals, how much less evidence such a pose may have and still count (as "
        "unrefined_rival_margin: a stereo view's twin one room along won by 0.03 of the submap explained).",
    )
    stronger_rival_below_explained: float = Field(
        0.95, ge=0,
        description="With tight_decision and the incremental input, a winner found before every submap plane was fed "
        "and explaining less than this fraction of the submap is held against one more round of triplets over the "
        "planes not yet fed: a refined pose elsewhere that matches more planes (less those in conflict) and explains "
        "as much rejects the query as ambiguous. 0 turns this off; above 1 every such winner is checked.",
    )
    stronger_rival_min_area_m2: float = Field(
        0.5, ge=0,
        description="...feeding only the planes of at least this area in that round (on a map of 2,000 planes all of "
        "a view's planes put two million map triplets and 0.14 s into it).",
    )
    rival_unknown_weight: float = Field(
        0.75, ge=0, le=1,
        description="With optimistic_rivals, how much of a match an unknown plane of a rival counts for (needs a "
        "map with free space; 1 = as a match, 0 = not at all), scaled down linearly with the fraction of the "
        "plane's place the map saw empty (none left at max_free_fraction).",
    )
    noisy_rival_unknown_weight: float = Field(
        0.5, ge=0, le=1,
        description="rival_unknown_weight for a sensor whose depth noise at 3 m is above noisy_sensor_sigma_m (never "
        "raised): with stereo noise the credit turned true poses away against rivals that matched fewer planes and "
        "left more of their submap where the map knows nothing (the suite's stereo, tuned and replicates A-E: +13 "
        "true poses at 0.5, no false positive; Kinect and ToF keep 0.75, where 0.5 let in 5 and 4 false "
        "positives).",
    )
    hidden_rival_credit: bool = Field(
        True,
        description="With optimistic_rivals and occlusion, a rival's credit for a plane unknown to the map also "
        "shrinks linearly with the share of the plane the map hides from the submap's cameras (none left at "
        "occlusion_min_fraction, where the plane counts against the rival): a door jamb that a twin pose puts half "
        "inside a wall is not half a match (the suite and its eight replicates: Kinect +2 true poses, ToF +7, no "
        "false positive more; stereo has occlusion off).",
    )
    sealed_rival_credit: bool = Field(
        False,
        description="With optimistic_rivals and hidden_rival_credit, where the sensor's noise turns occlusion off (a "
        "noisy sensor's map draws surface across the doorways the cameras saw through), a rival's credit for a "
        "plane unknown to the map still shrinks with the share of the plane behind a map surface that the map never "
        "saw past: no known free space between the surface and the plane (the outside of the building's outer "
        "wall). Only the credit changes, not the planes' states. Off by default: over the suite's nine stereo runs "
        "+19 true poses and +2 false positives (meeting rooms), and 2.9 ms more per query in the mean.",
    )
    footprint_rival_credit: bool = Field(
        True,
        description="With optimistic_rivals and hidden_rival_credit, a rival's credit for a plane unknown to the map "
        "also shrinks with the share of the plane's samples that the rival puts outside the map's footprint: the "
        "cells, seen from above, that hold a map sample or known free space, grown by footprint_margin_m (none left "
        "at occlusion_min_fraction). A stereo office view lost to a rival credited for a 3.8 m^2 wall 1.5 m beyond "
        "the outer wall, where no mapping ray went (docs/BENCHMARKS.md, 'A rival's credit outside the map's "
        "footprint': stereo +11 true poses over nine suites, no false positive more; Kinect and ToF unchanged).",
    )
    footprint_margin_m: float = Field(
        1.0,
        ge=0,
        description="How far beyond the map's samples and free space the footprint of footprint_rival_credit "
        "reaches (m): a noisy sensor's far samples scatter by decimetres (stereo at 7 m: 12 cm), and a pose a few "
        "tenths of a metre off pushes a wall's edge past the map's (0.5 m: one false positive more on the held-out "
        "replicate, once a rival turned 45 deg, whose walls stuck out by a quarter to a half of their samples, lost "
        "its credit).",
    )
    small_rival_credit: bool = Field(
        True,
        description="With optimistic_rivals, a rival's planes too small to count (under min_counted_area_m2) that "
        "land where the map knows nothing earn it credit too, judged as a plane that counts is (no map surface "
        "facing the same way near it; less credit for its share in known free space or hidden behind a map "
        "surface): a twin room the mapping runs covered less completely lacks the small faces of its furniture, "
        "which only the better-covered room's pose could match (the suite and its eight replicates, three sensors: "
        "7 false positives fewer, 6 of them views of the twin rooms or the symmetric room labelled ambiguous, for 8 "
        "true poses fewer).",
    )
    shared_unknown_credit: bool = Field(
        False,
        description="With optimistic_rivals, whether a rival that matches fewer planes than the winner still earns "
        "credit for the planes the winner leaves unknown to the map too, when the winner itself explains "
        "shared_unknown_min_explained of its submap. Such a plane says nothing about which of the two is right, "
        "yet the credit went to the rival alone (docs/BENCHMARKS.md, 'Planes neither pose explains': the suite and "
        "its nine replicates, three sensors, +19 true poses, no false positive more; True is the old behaviour).",
    )
    shared_unknown_min_explained: float = Field(
        0.9, ge=0,
        description="The explained fraction from which a winner's planes unknown to the map earn its weaker rivals no "
        "credit (shared_unknown_credit off); a winner that leaves more unknown keeps the rivals' credit as slack: "
        "at 0.85, a twin-room view labelled ambiguous was answered two rooms along.",
    )
    duplicate_credit_once: bool = Field(
        True,
        description="With optimistic_rivals, a rival's credit for a stack of duplicate submap planes (centroids "
        "within 3 cm, normals within 8 deg, map fusion's association limits: one surface fitted several times) "
        "counts once, each plane's credit divided by the stack's size. A stereo camera's small face 4-5 m away comes "
        "out of a window's fusion as up to a dozen such planes, and a corridor view's true pose was rejected "
        "against a rival credited for twelve (docs/BENCHMARKS.md, 'A surface fitted several times, credited once': "
        "the suite's stereo +1 true pose, its eleven replicates unchanged; Kinect and ToF have no duplicates). "
        "false = each plane credited (before 2026-12-03).",
    )
    evidence_area_m2: float = Field(
        1.0, gt=0, description="A matched plane's weight (Eq. 12-13) grows with its area up to this (small facets are "
        "weak evidence, and often clutter).",
    )
    min_ambiguity_ratio: float = Field(
        1.55, ge=1,
        description="Best mode must beat the runner-up at a different pose by this factor (1.5 before the path test: "
        "with it, a twin room that led the true one by 1.52 was answered; docs/BENCHMARKS.md, 'Camera paths "
        "through walls').",
    )
    distinct_translation_m: float = Field(0.25, gt=0, description="Modes farther apart than this are different poses...")
    distinct_rotation_deg: float = Field(5.0, gt=0, description="...or rotated by more than this.")

    @model_validator(mode="after")
    def _check(self) -> "EvaluationConfig":
        errors = [
            f"{name}: must be <= min_explained_fraction ({self.min_explained_fraction}), got {getattr(self, name)}"
            for name in ("min_explained_known_fraction", "min_competitor_fraction")
            if getattr(self, name) > self.min_explained_fraction
        ]
        if errors:
            raise ValueError("\n".join(errors))
        return self


class LiveConfig(_Section):
    """The live loop (``reloc run``)."""

    queue_frames: int = Field(4, ge=1, description="Capture queue length; when full the oldest frame is dropped.")
    reloc_period_s: float = Field(5.0, gt=0, description="Relocalize periodically to verify the pose.")
    lost_jump_m: float = Field(0.5, gt=0, description="Odometry jumping more than this between frames means lost.")
    status_period_s: float = Field(1.0, gt=0, description="How often the status line is printed.")
    realtime: bool = Field(True, description="Simulated and replayed sources run at their frame rate.")
    lost_jump_deg: float = Field(30.0, gt=0, description="...or turning more than this between frames.")
    lost_min_explained: float = Field(
        0.3, ge=0, le=1,
        description="Tracking check: planes of a frame, moved by the last verified pose and odometry, must match the "
        "map for at least this fraction of their area...",
    )
    lost_frames: int = Field(5, ge=1, description="...else after this many frames in a row tracking counts as lost.")
    search_period_s: float = Field(0.25, gt=0, description="While lost, relocalize at most this often.")
    stall_s: float = Field(1.0, gt=0, description="No frame from the source for this long is reported as a stall.")
    reconnect_backoff_s: BackoffSeq = Field(
        (0.1, 0.2, 0.5, 1.0, 2.0), description="Waits between reconnect attempts of a lost camera (the last repeats)."
    )
    odometry_drift_m_per_m: float = Field(
        0.025, ge=0,
        description="Tracked poses' covariance: the odometry's position drift (one sigma) per metre driven since the "
        "last relocalization, besides its heading error over half the path...",
    )
    odometry_heading_drift_per_turn: float = Field(
        0.01, ge=0, description="...its heading drift per angle turned (a gyro or wheel-base scale error)...")
    odometry_heading_drift_deg_per_m: float = Field(
        0.0, ge=0, description="...per metre driven (a heading from the wheels alone)...")
    odometry_heading_drift_deg_per_s: float = Field(
        0.115, ge=0, description="...and per second (a gyro's bias); benchmarks/tracked_covariance.py measures them.")


class SerialConfig(_Section):
    """The serial link to the robot's microcontroller."""

    url: str = Field("", description="pyserial URL: /dev/ttyACM0, loop://, socket://HOST:PORT; empty = no link.")
    baudrate: int = Field(921600, gt=0, description="Baud rate of a real port.")
    read_timeout_s: float = Field(0.05, gt=0, description="Read timeout of the reader thread.")
    write_timeout_s: float = Field(0.2, gt=0, description="A write blocked longer than this is reported.")
    reconnect_backoff_s: BackoffSeq = Field(
        (0.1, 0.2, 0.5, 1.0, 2.0), description="Waits between reopen attempts after an unplug (the last repeats)."
    )
    max_frame_bytes: int = Field(
        512, ge=144, le=65535,
        description="Longer frames are discarded and counted (the largest message, RelocPose, is 143 bytes encoded).",
    )
    pose_rate_hz: float = Field(
        10.0, gt=0, description="Poses sent on the host's own initiative at most this often (answers always go)."
    )
    heartbeat_period_s: float = Field(0.5, gt=0, description="Host heartbeat period (also the clock-sync sample rate).")
    status_period_s: float = Field(1.0, gt=0, description="Host status repeated this often, and sent on each change.")
    peer_timeout_s: float = Field(1.5, gt=0, description="The MCU counts as gone after this long without a frame.")
    time_sync_window_s: float = Field(
        20.0, gt=0, description="Window of the minimum-delay filter mapping MCU time to host time (follows clock drift)."
    )


class OakConfig(_Section):
    """OAK stereo camera through depthai 3 (`reloc record --camera oak`, `reloc run --camera oak`)."""

    preset: Literal["DEFAULT", "ROBOTICS", "ACCURACY", "DENSITY", "FAST_ACCURACY", "FAST_DENSITY", "HIGH_DETAIL",
                    "FACE"] = Field("DEFAULT", description="StereoDepth preset mode.")
    width: int = Field(640, ge=64, le=4096, description="Depth output width in pixels (mono cameras run at it).")
    height: int = Field(400, ge=64, le=4096, description="Depth output height in pixels.")
    fps: float = Field(30.0, gt=0, le=120, description="Camera frame rate.")
    subpixel: bool = Field(True, description="Subpixel disparity (finer depth steps far away).")
    lr_check: bool = Field(True, description="Left-right consistency check (removes occlusion errors).")
    extended_disparity: bool = Field(
        False, description="Extended disparity range (closer minimum depth; depthai 3.x cannot do it with subpixel).")
    align_to: Literal["left", "right", "rgb"] = Field("left", description="Camera whose view the depth is aligned to.")
    imu: bool = Field(True, description="Gravity from the IMU accelerometer when the device has one.")
    imu_rate_hz: int = Field(100, ge=1, le=500, description="Accelerometer report rate.")
    gravity_tau_s: float = Field(0.5, ge=0, description="Low-pass time constant of the accelerometer for gravity.")
    reconnect: bool = Field(True, description="Reconnect after an unplug or X_LINK error instead of stopping.")
    reconnect_backoff_s: BackoffSeq = Field(
        (0.5, 1.0, 2.0, 5.0), description="Waits between reconnect attempts (the last repeats)."
    )
    frame_timeout_s: float = Field(3.0, gt=0, description="No depth frame for this long counts as a disconnect.")
    search_timeout_s: float = Field(2.0, gt=0, description="How long to look for a device before giving up.")


class Config(_Section):
    """The whole configuration; every section has defaults, so an empty file is valid."""

    camera: CameraConfig = CameraConfig()
    oak: OakConfig = OakConfig()
    extraction: ExtractionConfig = ExtractionConfig()
    merging: MergingConfig = MergingConfig()
    mapping: MappingConfig = MappingConfig()
    matching: MatchingConfig = MatchingConfig()
    evaluation: EvaluationConfig = EvaluationConfig()
    live: LiveConfig = LiveConfig()
    serial: SerialConfig = SerialConfig()


class ConfigError(ValueError):
    """Every problem of a config file, each as ``path: message``."""

    def __init__(self, source: str, problems: list[str]):
        self.source = source
        self.problems = problems
        lines = "\n".join(f"  {p}" for p in problems)
        super().__init__(f"{source}: {len(problems)} problem(s) in the config:\n{lines}")


def default_config() -> Config:
    return Config()


def _duplicate_keys(node: yaml.Node, path: str = "") -> list[str]:
    """Paths of duplicate mapping keys anywhere in a composed YAML tree.

    Iterative, and each node is visited once: an alias shares its anchor's node, so a file of aliases of aliases
    (which would expand exponentially) costs no more than its own size.
    """
    problems = []
    stack = [(node, path)]
    visited: set[int] = set()
    while stack:
        node, path = stack.pop()
        if id(node) in visited:
            continue
        visited.add(id(node))
        if len(visited) > _MAX_YAML_NODES:
            problems.append(f"more than {_MAX_YAML_NODES} YAML nodes: not a config file")
            break
        children = []
        if isinstance(node, yaml.MappingNode):
            seen: dict[str, int] = {}
            for key_node, value_node in node.value:
                key = str(key_node.value)
                child = f"{path}.{key}" if path else key
                if key in seen:
                    problems.append(
                        f"{child}: duplicate key (first at line {seen[key] + 1}, again at line "
                        f"{key_node.start_mark.line + 1})"
                    )
                else:
                    seen[key] = key_node.start_mark.line
                children.append((value_node, child))
        elif isinstance(node, yaml.SequenceNode):
            children = [(item, f"{path}[{i}]") for i, item in enumerate(node.value)]
        stack.extend(reversed(children))
    return problems


_short_repr = reprlib.Repr()
_short_repr.maxstring = _short_repr.maxother = 80


def _format_pydantic(exc: ValidationError) -> list[str]:
    out = []
    for err in exc.errors():
        loc = ".".join(str(p) for p in err["loc"] if p != "__root__")
        msg = err["msg"]
        if msg.startswith("Value error, "):
            msg = msg[len("Value error, "):]
        if err["type"] == "extra_forbidden":
            msg = "unknown key"
        value = err.get("input")
        shown = "" if err["type"] in ("extra_forbidden", "missing") or isinstance(value, dict) else f", got {_short_repr.repr(value)}"
        if err["type"] == "value_error" and isinstance(value, dict):
            # A section-level check reports several fields at once, each as "field: message".
            out.extend(f"{loc}.{line}" if loc else line for line in msg.split("\n"))
            continue
        out.append(f"{loc}: {msg}{shown}" if loc else f"{msg}{shown}")
    return out


def config_from_dict(data: Any, source: str = "<config>") -> Config:
    """Validate a plain mapping (as loaded from YAML) into a :class:`Config`."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(source, [f"expected a mapping of sections at the top level, got {type(data).__name__}"])
    # A section with every key commented out is YAML's null: its defaults, as an empty file has.
    data = {k: ({} if v is None else v) for k, v in data.items()}
    try:
        return Config.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(source, _format_pydantic(exc)) from None


class YamlLoader(yaml.SafeLoader):
    """PyYAML's safe loader, reading ``2e-3`` as a number as YAML 1.2 does (PyYAML follows YAML 1.1, which wants
    ``2.0e-3``, so a config's ``noise_coeff: 2e-3`` was refused as text)."""


YamlLoader.add_implicit_resolver("tag:yaml.org,2002:float", re.compile(r"^[-+]?[0-9][0-9_]*[eE][-+]?[0-9]+$"),
                                 list("-+0123456789"))


def load_yaml(text: str):
    """``yaml.safe_load`` with :class:`YamlLoader`."""
    return yaml.load(text, Loader=YamlLoader)  # noqa: S506 - a SafeLoader subclass


def load_config(path: str | Path | None) -> Config:
    """Load and validate a YAML config file; ``None`` gives the defaults. Raises :class:`ConfigError`."""
    if path is None:
        return Config()
    path = Path(path)
    source = str(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ConfigError(source, [f"cannot read the file: {exc.strerror or exc}"]) from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(source, [f"not UTF-8 text (byte {exc.start}): expected a YAML file"]) from None
    try:
        node = yaml.compose(io.StringIO(text), Loader=YamlLoader)
        data = load_yaml(text)
    except yaml.YAMLError as exc:
        raise ConfigError(source, [f"not valid YAML: {exc}"]) from None
    except RecursionError:
        raise ConfigError(source, ["YAML nested too deeply: not a config file"]) from None
    problems = _duplicate_keys(node) if node is not None else []
    try:
        cfg = config_from_dict(data, source)
    except ConfigError as exc:
        problems.extend(exc.problems)
        cfg = None
    if problems:
        raise ConfigError(source, problems)
    return cfg


def config_as_dict(cfg: Config) -> dict:
    """Plain nested dict (tuples as lists), ready for YAML or JSON."""

    def plain(v):
        if isinstance(v, dict):
            return {k: plain(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [plain(x) for x in v]
        return v

    return plain(cfg.model_dump())


def dump_config(cfg: Config | None = None, *, comments: bool = True) -> str:
    """The config as YAML; with ``comments`` each field carries its description."""
    cfg = cfg or Config()
    data = config_as_dict(cfg)
    if not comments:
        return yaml.safe_dump(data, sort_keys=False)
    lines = ["# voxelplane-reloc configuration (units in the key names; degrees only here and in reports)"]
    for section_name, section_field in Config.model_fields.items():
        section_cls = section_field.annotation
        lines.append("")
        lines.append(f"# {section_cls.__doc__.strip().splitlines()[0]}")
        lines.append(f"{section_name}:")
        for name, field in section_cls.model_fields.items():
            value = yaml.safe_dump(data[section_name][name], default_flow_style=True, width=10_000).strip()
            if value.endswith("\n..."):
                value = value[: -len("\n...")]
            value = value.removesuffix("...").strip()
            lines.append(f"  {name}: {value}  # {field.description}")
    return "\n".join(lines) + "\n"


def with_noise_law(cfg: Config, law: "tuple[str, float] | None", origin: str) -> "tuple[Config, str | None]":
    """``(cfg, note)``: ``cfg`` with ``law`` (``(noise_model, noise_coeff)``, known from ``origin``: "the camera", "the
    recording") as its extraction noise law, unless the config names a law itself (``extraction.noise_model`` or
    ``noise_coeff`` given) or ``law`` is None; then ``cfg`` unchanged and ``note`` None.

    Extraction's planarity tests, weights and merging thresholds, the odometry check of submaps and the matcher's
    decision offsets all scale with this law. The default (Kinect, 1.425e-3 z^2) is 1.7x too small for an OAK-D at
    640x400: its stereo planes would be fitted as if they were twice as certain as they are.
    """
    ex = cfg.extraction
    if law is None or {"noise_model", "noise_coeff"} & ex.model_fields_set:
        return cfg, None
    model, coeff = law
    if (model, coeff) == (ex.noise_model, ex.noise_coeff):
        return cfg, None
    from reloc.extraction.params import ExtractionParams, noise_law_code

    section = ex.model_copy(update={"noise_model": model, "noise_coeff": float(coeff)})
    text = f"{float(coeff):.3g}" + {0: "", 1: " z", 2: " z^2"}[noise_law_code(model)]
    note = (f"depth noise: {model}, sigma = {text} m, from {origin} (extraction.noise_model / noise_coeff in the "
            "config override it)")
    if cfg.merging.layer_min_shared is None and ExtractionParams(noise_model=model).layer_share > 0:
        note += "; planes that are layers of its disparity steps are merged (merging.layer_min_shared: 0 stops it)"
    return cfg.model_copy(update={"extraction": section}), note
