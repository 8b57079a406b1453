"""Plain parameters of plane extraction and merging, and the sensor noise law they use.

:class:`ExtractionParams` is what every extraction function takes; it is built from the config at the edges
(:meth:`ExtractionParams.from_config`) and holds metres and radians only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace

import numpy as np

__all__ = ["ExtractionParams", "NOISE_MODELS", "noise_sigma", "noise_law_code"]

# Noise law of a depth measurement at depth z (metres): sigma_z = coeff * z**power.
NOISE_MODELS = {"constant": 0, "tof": 1, "kinect": 2, "stereo": 2}
NOISE_DIRECTIONS = ("ray", "normal")
GRAVITY_FALLBACKS = ("camera_y", "mounting", "none")
# The layer merge's share for a stereo camera when none is set (docs/BENCHMARKS.md, "Stereo's layers merged by
# default"): layers are a stereo camera's, so every other sensor's planes are not merged that way.
STEREO_LAYER_MIN_SHARED = 0.5


def noise_law_code(noise_model: str) -> int:
    """The exponent of depth in the noise law of ``noise_model`` (0, 1 or 2), as the kernels take it."""
    if noise_model not in NOISE_MODELS:
        raise ValueError(f"noise_model: expected one of {sorted(NOISE_MODELS)}, got {noise_model!r}")
    return NOISE_MODELS[noise_model]


def noise_sigma(z_m: np.ndarray | float, noise_model: str = "kinect", noise_coeff: float = 1.425e-3) -> np.ndarray:
    """Standard deviation (m) of a depth measurement at depth ``z_m`` (m) under ``noise_model``."""
    return noise_coeff * np.abs(np.asarray(z_m, dtype=np.float64)) ** noise_law_code(noise_model)


@dataclass(frozen=True)
class ExtractionParams:
    """Everything extraction and merging need, as plain values (metres, radians).

    Depth to points: ``min_depth_m``, ``max_depth_m``, ``pixel_stride``; ``flying_pixel_sigmas`` > 0 first drops
    every pixel beside a depth jump of more than that many noise sigmas (and 3 % of the depth): flying pixels
    between two surfaces and both sides of the edge (0 = off, the default; see docs/BENCHMARKS.md, "Flying pixels").
    Voxels and planarity: ``voxel_size_m``, ``min_points_per_voxel``; a voxel holds a plane when the RMS distance of
    its points to their PCA plane is below ``max(max_thickness_sigmas * sigma(z), max_thickness_floor_m)`` and the
    smallest / middle eigenvalue ratio, after the noise variance is taken off the smallest, is below
    ``max_eigen_ratio``, and the normal's angular standard deviation ``sqrt(l0 / (n l1))`` is below
    ``max_normal_std_rad``.
    Weighted refit (paper Eq. 2-3 and beyond), each ingredient switchable:
    - ``adaptive_weights``: the paper's position weight ``1 - alpha rho^2`` for ``rho <= 1/2``, ``exp(-beta rho^2)``
      beyond, with ``rho`` the distance to the plane centre over the largest such distance (off = VR-NE). On by
      default: in benchmarks/extraction_accuracy.py it lowers the tail errors of whole frames (protocol 2: voxels
      that hold a corner), while on single planes (protocol 1) it does not help (up to 0.005 deg and 0.5 mm worse).
    - ``noise_weights``: ``1 / sigma_i^2`` from the noise law ``sigma_z = noise_coeff * z^k`` (``noise_model``).
      With ``noise_direction="ray"`` the depth noise moves a point along its viewing ray, so its distance to the
      plane varies by ``sigma_z |n . ray| / ray_z`` (incidence taken into account); with ``"normal"`` the noise is
      taken along the plane normal (``sigma_z`` itself), as in the paper's synthetic Table 2 protocol.
    - ``irls_iterations`` passes of residual-based reweighting with Tukey's biweight of width
      ``irls_kernel_sigmas`` in units of the (robustly rescaled) per-point sigma. Voxels with more than
      ``voxel_fit_max_points`` points are refit from an even subsample (their plane only steers the merging; the
      merged planes are refined from all points). With the robust weight the planarity test is made again on
      the refit's inliers, whose Tukey weights must sum to at least ``min_inlier_fraction`` of the voxel's points
      (a weighted share of inliers: a voxel of a clean plane with Gaussian noise scores about 0.81, so a value above
      0.8 refuses planar voxels).
    Single point sets (:func:`fit_plane`): ``ransac_hypotheses`` three-point hypotheses scored by a truncated
    sigma-normalised cost give the robust start of the IRLS (0 = start from the noise-weighted PCA); ``seed`` makes
    it repeatable.
    Merging: ``merge`` (off = VR-NM); growth over the 26-neighbourhood accepts a neighbour voxel whose normal is
    within ``max(grow_max_angle_rad, atan(grow_angle_noise_sigmas * sigma(z) / spread))`` of the growing plane,
    whose centroid lies within ``max(grow_max_offset_m, grow_offset_sigmas * sigma(z))`` of it and whose
    points lie on it within the planarity thickness (a 2 cm floor: with 4 cm a voxel holding a wall and a door 6 cm
    behind it joined at 3 m and carried the growing plane onto the door). Under-grown fragments merge when their
    normals are within ``undergrown_max_angle_rad``, the other's centroid lies off the larger fragment's plane by
    at most the depth angle (``undergrown_max_depth_angle_rad`` off perpendicular to its normal, over the
    centroid-to-centroid distance) and at most ``undergrown_max_offset_m`` (both tests; each at least
    ``grow_offset_sigmas`` depth sigmas), and the centroids are within ``undergrown_radius_scale`` times the larger
    radius. Layers (frames only, with merging on): two planes whose normals are within
    ``undergrown_max_angle_rad``, the smaller one's centroid within ``max_thickness_sigmas`` depth sigmas of the
    larger plane, and which share at least ``layer_min_shared`` of the smaller one's blocks of 2x2 pixels used are one
    surface seen through the same rays (stereo's disparity steps cut a far wall into such layers): they become one
    plane, refit from both (0 = never; None, the default, is 0.5 with a stereo camera's noise law and 0 with every
    other: :attr:`layer_share`; see docs/BENCHMARKS.md, "Stereo's far walls in layers" and "Stereo's layers merged by
    default").
    Plane set: ``area_patch_m`` (l of the area count), ``sample_spacing_m``, ``inlier_sigmas`` (points of a
    plane's voxels farther than this many sigmas are not labelled as the plane), ``refine_boundary`` (points of
    neighbouring voxels join it when inside that band), ``refine_iterations`` (robust passes over the points near
    each merged plane: refit, then fragments merge again; 0 = planes straight from the merged moments),
    ``corner_min_angle_rad`` (the refinement's corner test: a point whose pixel ray meets another candidate plane
    at least this far off in angle near where it meets its own is a corner point, left out of the refit; closer
    candidates are pieces of one surface. At 10 deg instead of 20 a strip across a step between parallel surfaces,
    such as a door in a 6 cm niche, tilted 13-18 deg, counts as the bevel it is and the planes of whole frames come
    out cleaner, but relocalization lost true poses: see docs/BENCHMARKS.md, "A door in a niche"),
    ``bevel_max_width_voxels`` (None: any plane made mostly of corner points is dropped as a bevel across the
    corner; a number: only one at most this many voxels wide across its shorter in-plane axis, since voxels holding
    two surfaces make a strip along their corner about a voxel wide. Off by default: see docs/BENCHMARKS.md,
    "Bevels no wider than a strip", for what it does to stereo planes and to relocalization),
    ``min_plane_points``,
    ``min_plane_area_m2``; ``gravity_fallback`` says what a frame without ``gravity_cam`` (an IMU's) gets: the
    camera's +y axis (``"camera_y"``; the plane set's ``gravity_tolerance_rad`` is then ``camera_tilt_tolerance_rad``,
    the paper's allowance for a camera mounted with a tilt), ``mounting_gravity_cam`` (``"mounting"``: a level base,
    the direction fixed by how the camera is mounted) or no gravity (``"none"``).
    """

    min_depth_m: float = 0.3
    max_depth_m: float = 8.0
    pixel_stride: int = 1
    voxel_size_m: float = 0.25
    min_points_per_voxel: int = 12
    max_thickness_sigmas: float = 4.0
    max_thickness_floor_m: float = 0.01
    max_eigen_ratio: float = 0.05
    max_normal_std_rad: float = math.radians(5.0)
    adaptive_weights: bool = True
    alpha: float = 0.5
    beta: float = 2.0
    noise_weights: bool = True
    noise_direction: str = "ray"
    irls_iterations: int = 3
    irls_kernel_sigmas: float = 3.0
    voxel_fit_max_points: int = 256
    min_inlier_fraction: float = 0.7
    noise_model: str = "kinect"
    noise_coeff: float = 1.425e-3
    ransac_hypotheses: int = 256
    seed: int = 0
    merge: bool = True
    grow_max_angle_rad: float = math.radians(10.0)
    grow_max_offset_m: float = 0.02
    grow_offset_sigmas: float = 2.0
    grow_angle_noise_sigmas: float = 2.0
    undergrown_max_angle_rad: float = math.radians(8.0)
    undergrown_max_depth_angle_rad: float = math.radians(5.0)
    undergrown_max_offset_m: float = 0.05
    undergrown_radius_scale: float = 2.0
    layer_min_shared: float | None = None
    flying_pixel_sigmas: float = 0.0
    area_patch_m: float = 0.1
    sample_spacing_m: float = 0.1
    inlier_sigmas: float = 4.0
    refine_boundary: bool = True
    refine_iterations: int = 2
    corner_min_angle_rad: float = math.radians(20.0)
    bevel_max_width_voxels: float | None = None
    min_plane_points: int = 200
    min_plane_area_m2: float = 0.04
    gravity_fallback: str = "camera_y"
    camera_tilt_tolerance_rad: float = math.radians(20.0)
    mounting_gravity_cam: tuple = (0.0, 1.0, 0.0)

    def __post_init__(self) -> None:
        positive = (
            "max_depth_m", "voxel_size_m", "max_thickness_sigmas", "max_eigen_ratio", "max_normal_std_rad",
            "min_inlier_fraction",
            "irls_kernel_sigmas",
            "noise_coeff", "grow_max_angle_rad", "grow_max_offset_m", "undergrown_max_angle_rad",
            "undergrown_max_depth_angle_rad", "undergrown_max_offset_m", "undergrown_radius_scale", "area_patch_m",
            "sample_spacing_m", "inlier_sigmas", "corner_min_angle_rad",
        )
        for name in positive:
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ValueError(f"ExtractionParams.{name}: expected a finite number > 0, got {v!r}")
        non_negative = ("min_depth_m", "max_thickness_floor_m", "alpha", "beta", "grow_offset_sigmas",
                        "grow_angle_noise_sigmas",
                        "min_plane_area_m2", "flying_pixel_sigmas")
        for name in non_negative:
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
                raise ValueError(f"ExtractionParams.{name}: expected a finite number >= 0, got {v!r}")
        if self.corner_min_angle_rad > math.pi / 2:
            raise ValueError(f"ExtractionParams.corner_min_angle_rad: expected at most pi/2, got "
                             f"{self.corner_min_angle_rad!r}")
        ls = self.layer_min_shared
        if ls is not None and (isinstance(ls, bool) or not isinstance(ls, (int, float)) or not 0 <= ls <= 1):
            raise ValueError(f"ExtractionParams.layer_min_shared: expected None (by the sensor) or a number in [0, 1], "
                             f"got {ls!r}")
        bw = self.bevel_max_width_voxels
        if bw is not None and (isinstance(bw, bool) or not isinstance(bw, (int, float)) or not math.isfinite(bw)
                               or bw <= 0):
            raise ValueError(
                f"ExtractionParams.bevel_max_width_voxels: expected None or a finite number > 0, got {bw!r}"
            )
        if self.max_depth_m <= self.min_depth_m:
            raise ValueError(
                f"ExtractionParams.max_depth_m: expected > min_depth_m ({self.min_depth_m}), got {self.max_depth_m}"
            )
        for name, lo in (("pixel_stride", 1), ("min_points_per_voxel", 3), ("irls_iterations", 0),
                         ("ransac_hypotheses", 0), ("min_plane_points", 3), ("seed", 0),
                         ("refine_iterations", 0), ("voxel_fit_max_points", 3)):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < lo:
                raise ValueError(f"ExtractionParams.{name}: expected an integer >= {lo}, got {v!r}")
        for name in ("adaptive_weights", "noise_weights", "merge", "refine_boundary"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise ValueError(f"ExtractionParams.{name}: expected a bool, got {getattr(self, name)!r}")
        noise_law_code(self.noise_model)
        if self.noise_direction not in NOISE_DIRECTIONS:
            raise ValueError(f"ExtractionParams.noise_direction: expected one of {NOISE_DIRECTIONS}, "
                             f"got {self.noise_direction!r}")
        tilt = self.camera_tilt_tolerance_rad
        if isinstance(tilt, bool) or not isinstance(tilt, (int, float)) or not 0 <= tilt <= math.pi / 2:
            raise ValueError(f"ExtractionParams.camera_tilt_tolerance_rad: expected a number in [0, pi/2], got {tilt!r}")
        g = self.mounting_gravity_cam
        try:
            g = tuple(float(v) for v in g)
        except (TypeError, ValueError):
            g = ()
        if len(g) != 3 or not all(math.isfinite(v) for v in g) or math.hypot(*g) < 1e-9:
            raise ValueError(f"ExtractionParams.mounting_gravity_cam: expected a non-zero 3-vector, got "
                             f"{self.mounting_gravity_cam!r}")
        norm = math.hypot(*g)
        object.__setattr__(self, "mounting_gravity_cam", tuple(v / norm for v in g))
        if self.gravity_fallback not in GRAVITY_FALLBACKS:
            raise ValueError(f"ExtractionParams.gravity_fallback: expected one of {GRAVITY_FALLBACKS}, "
                             f"got {self.gravity_fallback!r}")

    @property
    def bevel_max_width_m(self) -> float:
        """``bevel_max_width_voxels`` in metres (inf when None: no limit)."""
        bw = self.bevel_max_width_voxels
        return math.inf if bw is None else bw * self.voxel_size_m

    @property
    def layer_share(self) -> float:
        """The layer merge's ``layer_min_shared`` in effect: the set value, or when it is None (the default)
        :data:`STEREO_LAYER_MIN_SHARED` for a stereo camera's noise law (whose disparity steps make the layers) and 0
        (no merge) for every other sensor."""
        if self.layer_min_shared is not None:
            return float(self.layer_min_shared)
        return STEREO_LAYER_MIN_SHARED if self.noise_model == "stereo" else 0.0

    @property
    def noise_power(self) -> int:
        """Exponent ``k`` of the noise law ``sigma_z = noise_coeff * z**k``."""
        return noise_law_code(self.noise_model)

    def with_(self, **changes) -> "ExtractionParams":
        """A copy with some fields changed (unknown names raise ValueError)."""
        known = {f.name for f in fields(self)}
        unknown = sorted(set(changes) - known)
        if unknown:
            raise ValueError(f"ExtractionParams: unknown parameter(s) {unknown}; expected some of {sorted(known)}")
        return replace(self, **changes)

    @classmethod
    def from_config(cls, cfg) -> "ExtractionParams":
        """Parameters from a :class:`reloc.config.Config` (its camera, extraction and merging sections)."""
        cam, ex, mg = cfg.camera, cfg.extraction, cfg.merging
        known = {f.name for f in fields(cls)}
        # Extraction fields named like ours pass through; degrees become radians.
        kwargs = {name: getattr(ex, name) for name in type(ex).model_fields if name in known}
        for name in type(ex).model_fields:
            if name.endswith("_deg") and name[: -len("_deg")] + "_rad" in known:
                kwargs[name[: -len("_deg")] + "_rad"] = math.radians(getattr(ex, name))
        kwargs.update(
            min_depth_m=cam.min_depth_m,
            max_depth_m=cam.max_depth_m,
            pixel_stride=cam.pixel_stride,
            gravity_fallback={"camera_y": "camera_y", "mounting": "mounting"}.get(cam.gravity_source, "none"),
            camera_tilt_tolerance_rad=math.radians(cam.max_tilt_deg),
            # Base z up: gravity (0, 0, -1) in the base frame, R_base_cam^T of it in the camera frame.
            mounting_gravity_cam=tuple(-np.asarray(cam.T_base_cam, dtype=np.float64).reshape(4, 4)[2, :3]),
            merge=mg.enabled,
        )
        for name in type(mg).model_fields:
            if name == "enabled":
                continue
            if name.endswith("_deg") and name[: -len("_deg")] + "_rad" in known:
                kwargs[name[: -len("_deg")] + "_rad"] = math.radians(getattr(mg, name))
            elif name in known:
                kwargs[name] = getattr(mg, name)
        return cls(**kwargs)
