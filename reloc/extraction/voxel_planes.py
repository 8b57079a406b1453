"""Stages 3 and 4: the plane of each voxel (PCA, planarity test), then its weighted refit (paper Eq. 2-3 and more).

Points are in the sensor frame with the sensor at the origin (z its viewing direction, the depth of the noise law).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from reloc.extraction import _kernels_voxelfit as kvf
from reloc.extraction._workspace import Workspace, fresh
from reloc.extraction.params import noise_law_code
from reloc.extraction.voxelize import VoxelGrid

__all__ = ["VoxelPlanes", "fit_voxel_planes", "refine_voxel_planes", "FEW", "NOT_PLANAR", "PLANAR"]

FEW, NOT_PLANAR, PLANAR = kvf.FEW, kvf.NOT_PLANAR, kvf.PLANAR


@dataclass(frozen=True)
class VoxelPlanes:
    """Per voxel (V rows; arrays may be workspace views):

    - ``flags`` int8: ``FEW`` / ``NOT_PLANAR`` / ``PLANAR``; ``planes`` (V, 4) ``[n, d]`` toward the sensor;
    - ``eigenvalues`` (V, 3) ascending, of the PCA point covariance; ``normal_std`` (V,) radians;
    - after :func:`refine_voxel_planes`: weighted moments about the origin ``wmoments`` (V, 4) ``[W, sum w p]`` and
      ``wscatters`` (V, 3, 3) ``sum w p p^T``, ``n_eff`` (V,) points with non-zero weight, ``radius`` (V,) largest
      distance of a voxel point from the voxel centroid (zero until refined).
    """

    flags: np.ndarray
    planes: np.ndarray
    eigenvalues: np.ndarray
    normal_std: np.ndarray
    wmoments: np.ndarray
    wscatters: np.ndarray
    n_eff: np.ndarray
    radius: np.ndarray

    @property
    def planar(self) -> np.ndarray:
        """Ids of the planar voxels."""
        return np.flatnonzero(self.flags == PLANAR)


def fit_voxel_planes(
    grid: VoxelGrid,
    *,
    min_points_per_voxel: int = 12,
    noise_model: str = "kinect",
    noise_coeff: float = 1.425e-3,
    max_thickness_sigmas: float = 4.0,
    max_thickness_floor_m: float = 0.01,
    max_eigen_ratio: float = 0.05,
    max_normal_std_rad: float = np.radians(5.0),
    workspace: Workspace | None = None,
) -> VoxelPlanes:
    """PCA plane of every voxel from its moments and the planarity test (see ``_kernels_voxelfit``)."""
    ws = fresh(workspace)
    nv = len(grid)
    flags = ws.get("vp_flags", nv, np.int8)
    planes = ws.get("vp_planes", (nv, 4), np.float64)
    eig = ws.get("vp_eig", (nv, 3), np.float64)
    nstd = ws.get("vp_nstd", nv, np.float64)
    if nv:
        kvf.voxel_pca_planes(
            grid.counts, grid.sums, grid.scatters, nv, int(min_points_per_voxel), noise_law_code(noise_model),
            float(noise_coeff), float(max_thickness_sigmas), float(max_thickness_floor_m), float(max_eigen_ratio),
            float(max_normal_std_rad), planes, eig, nstd, flags,
        )
    wmom = ws.get("vp_wmom", (nv, 4), np.float64)
    wscat = ws.get("vp_wscat", (nv, 3, 3), np.float64)
    neff = ws.get("vp_neff", nv, np.int64)
    radius = ws.get("vp_radius", nv, np.float64)
    wmom[:] = 0.0
    wscat[:] = 0.0
    neff[:] = 0
    radius[:] = 0.0
    return VoxelPlanes(flags, planes, eig, nstd, wmom, wscat, neff, radius)


def refine_voxel_planes(
    grid: VoxelGrid,
    vp: VoxelPlanes,
    *,
    noise_model: str = "kinect",
    noise_coeff: float = 1.425e-3,
    noise_direction: str = "ray",
    noise_weights: bool = True,
    adaptive_weights: bool = True,
    alpha: float = 0.5,
    beta: float = 2.0,
    irls_iterations: int = 3,
    irls_kernel_sigmas: float = 3.0,
    voxel_fit_max_points: int = 256,
    max_thickness_sigmas: float = 4.0,
    max_thickness_floor_m: float = 0.01,
    max_eigen_ratio: float = 0.05,
    max_normal_std_rad: float = np.radians(5.0),
    min_inlier_fraction: float = 0.7,
) -> VoxelPlanes:
    """Weighted refit of the planar voxels of ``vp`` from their points, in place (returns ``vp``).

    Weights: Eq. 2 position weight (``adaptive_weights``; off = the paper's VR-NE) x ``1 / sigma^2`` of the noise
    law (``noise_weights``; ``noise_direction`` "ray" or "normal") x Tukey's biweight on the residual over sigma
    (``irls_iterations`` passes, 0 = off). ``noise_direction`` ("ray" or "normal") sets each point's sigma and
    weight; the plane itself is solved by weighted total least squares either way (the voxel faces cut the noisy
    surface along the depth axis, which biases the ray-form regression more). Also fills the weighted
    moments, ``n_eff`` and ``radius``. Voxels with more than ``voxel_fit_max_points`` points are refit from an even
    subsample of them (weights scaled up to stand for all). With the robust weight the planarity test is made
    again on the inliers (same thresholds as :func:`fit_voxel_planes`, plus ``min_inlier_fraction`` of Tukey
    weight), so voxels with a little of another surface count as planar.
    """
    if noise_direction not in ("ray", "normal"):
        raise ValueError(f"noise_direction: expected 'ray' or 'normal', got {noise_direction!r}")
    nv = len(grid)
    if nv:
        kvf.voxel_weighted_refit(
            grid.points, grid.points.view(np.int32), grid.start, nv, grid.counts, grid.sums, vp.flags, vp.eigenvalues,
            noise_law_code(noise_model), float(noise_coeff), noise_direction == "ray", bool(noise_weights),
            bool(adaptive_weights), float(alpha), float(beta), int(irls_iterations), float(irls_kernel_sigmas),
            int(voxel_fit_max_points), float(max_thickness_sigmas), float(max_thickness_floor_m),
            float(max_eigen_ratio), float(max_normal_std_rad), float(min_inlier_fraction),
            vp.planes, vp.wmoments, vp.wscatters, vp.n_eff, vp.radius,
        )
    return vp
