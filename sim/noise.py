"""Depth noise models of real sensors, seeded and deterministic.

Each model turns a noise-free depth image (and its plane labels) into what a sensor would report:

- ``none``: the exact depth (range limits only).
- ``kinect``: Kinect v1 structured light, Gaussian with ``sigma_z = 1.425e-3 z^2`` m (Nguyen et al. 2012).
- ``stereo``: OAK-D class stereo; the error lives in disparity ``disp = f b / z``: Gaussian disparity noise of
  ``sigma_disp_px`` then quantization to ``1 / subpixel_steps`` px, so the depth error grows as ``z^2 / (f b)``.
- ``tof``: time of flight; ``sigma = (a + b z) (1 + c r^2)`` with ``r`` the distance from the principal point
  normalised to 1 at the image corner: error grows with depth and toward the image edges (as the paper observed),
  and so do dropouts.

Every model also has range limits, missing pixels (random dropouts, more at the edges for ToF) and flying pixels:
on the far side of a depth discontinuity a pixel may report a depth between the two surfaces. Flying, missing and
out-of-range pixels lose their label (0), so a labelled pixel always measures its plane with the model's noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from reloc.camera import Intrinsics

__all__ = ["NoiseModel", "make_noise", "NOISE_NAMES"]

NOISE_NAMES = ("none", "stereo", "kinect", "tof")


@dataclass(frozen=True)
class NoiseModel:
    """Parameters of one sensor noise model (see the module docstring). Build with :func:`make_noise`."""

    name: str
    min_range_m: float = 0.0
    max_range_m: float = math.inf
    missing_fraction: float = 0.0
    flying_probability: float = 0.0
    discontinuity_rel: float = 0.05
    # kinect: sigma = kinect_coeff z^2
    kinect_coeff: float = 1.425e-3
    # stereo
    baseline_m: float = 0.075
    sigma_disp_px: float = 0.08
    subpixel_steps: int = 8
    # tof: sigma = (tof_a + tof_b z) (1 + tof_edge r^2), dropouts missing_fraction + tof_edge_missing r^4
    tof_a_m: float = 2e-3
    tof_b: float = 2e-3
    tof_edge: float = 1.5
    tof_edge_missing: float = 0.08

    def __post_init__(self) -> None:
        if self.name not in NOISE_NAMES:
            raise ValueError(f"NoiseModel.name: expected one of {', '.join(NOISE_NAMES)}, got {self.name!r}")
        if not (0 <= self.min_range_m < self.max_range_m):
            raise ValueError(f"NoiseModel range: expected 0 <= min_range_m < max_range_m, got "
                             f"{self.min_range_m}, {self.max_range_m}")
        for f in ("missing_fraction", "flying_probability"):
            v = getattr(self, f)
            if not 0 <= v <= 1:
                raise ValueError(f"NoiseModel.{f}: expected a probability in [0, 1], got {v}")

    def extraction_law(self, focal_px: float) -> tuple[str, float] | None:
        """``(noise_model, noise_coeff)`` of the extraction's noise law for this sensor at focal length
        ``focal_px`` (:mod:`reloc.extraction.params`): kinect ``kinect_coeff z^2``; stereo ``sigma_disp_px / (f b)
        z^2``; ToF ``~ b z`` with its constant term folded in at 2 m. None for the noise-free model."""
        if self.name == "kinect":
            return "kinect", float(self.kinect_coeff)
        if self.name == "stereo":
            return "stereo", float(self.sigma_disp_px / (abs(focal_px) * self.baseline_m))
        if self.name == "tof":
            return "tof", float(self.tof_b + self.tof_a_m / 2.0)
        return None

    # -- the error model ------------------------------------------------------------------------------------------
    def radius_map(self, intrinsics: Intrinsics) -> np.ndarray:
        """(H, W) distance of each pixel from the principal point, 1 at the farthest image corner."""
        H, W = intrinsics.shape
        u = np.arange(W, dtype=np.float64) - intrinsics.cx
        v = np.arange(H, dtype=np.float64) - intrinsics.cy
        r = np.hypot(u[None, :], v[:, None])
        return r / r.max()

    def sigma_m(self, depth_m: np.ndarray, radius: np.ndarray | float = 0.0, focal_px: float = 525.0) -> np.ndarray:
        """Standard deviation (m) of the depth error at true depth ``depth_m`` (and normalised radius for ToF;
        focal length in pixels for stereo)."""
        z = np.asarray(depth_m, dtype=np.float64)
        if self.name == "kinect":
            return self.kinect_coeff * z * z
        if self.name == "stereo":
            return z * z * self.sigma_disp_px / (focal_px * self.baseline_m)
        if self.name == "tof":
            r = np.asarray(radius, dtype=np.float64)
            return (self.tof_a_m + self.tof_b * z) * (1.0 + self.tof_edge * r * r)
        return np.zeros_like(z)

    def max_error_m(self, depth_m: np.ndarray, radius: np.ndarray | float = 0.0, focal_px: float = 525.0,
                    n_sigma: float = 6.0) -> np.ndarray:
        """Bound on ``|measured - true|`` depth for a labelled pixel: ``n_sigma`` standard deviations, plus the
        disparity quantization for stereo (exact, not linearised)."""
        z = np.asarray(depth_m, dtype=np.float64)
        if self.name == "stereo":
            fb = focal_px * self.baseline_m
            e = n_sigma * self.sigma_disp_px + 0.5 / self.subpixel_steps  # disparity error bound, px
            with np.errstate(divide="ignore"):
                return np.where(fb > z * e, z * z * e / np.maximum(fb - z * e, 1e-300), np.inf)
        return n_sigma * self.sigma_m(z, radius, focal_px)

    # -- apply ----------------------------------------------------------------------------------------------------
    def apply(self, depth_m: np.ndarray, labels: np.ndarray, intrinsics: Intrinsics,
              rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Noisy depth (float32, NaN = no measurement) and the labels of the pixels that still measure their plane.

        ``depth_m`` (H, W) noise-free (NaN = nothing), ``labels`` (H, W) int32. Deterministic given ``rng``'s state.
        """
        from sim import _noise_kernels as _k

        if np.shape(depth_m) != intrinsics.shape or np.shape(labels) != intrinsics.shape:
            raise ValueError(f"depth_m, labels: expected shape {intrinsics.shape}, got {np.shape(depth_m)}, "
                             f"{np.shape(labels)}")
        z = np.ascontiguousarray(depth_m, dtype=np.float32)
        lab = np.ascontiguousarray(labels, dtype=np.int32)
        H, W = z.shape
        # Draws in a fixed order, so the result depends on the seed only.
        if self.name == "none":
            gauss = np.zeros((H, W), np.float32)
        else:
            gauss = rng.standard_normal((H, W), dtype=np.float32)
        if self.missing_fraction > 0 or (self.name == "tof" and self.tof_edge_missing > 0):
            u_miss = rng.random((H, W), dtype=np.float32)
        else:
            u_miss = np.ones((H, W), np.float32)  # never below a zero dropout probability
        cand = np.zeros((H, W), dtype=np.bool_)
        n_cand = _k.flying_candidates(z, float(self.discontinuity_rel), cand) if self.flying_probability > 0 else 0
        u_fly = rng.random(n_cand, dtype=np.float32)
        a_fly = rng.random(n_cand, dtype=np.float32)
        kind = {"none": _k.KIND_NONE, "kinect": _k.KIND_KINECT, "stereo": _k.KIND_STEREO, "tof": _k.KIND_TOF}[self.name]
        corner = max(np.hypot(intrinsics.cx, intrinsics.cy), np.hypot(W - 1 - intrinsics.cx, intrinsics.cy),
                     np.hypot(intrinsics.cx, H - 1 - intrinsics.cy), np.hypot(W - 1 - intrinsics.cx, H - 1 - intrinsics.cy))
        out = np.empty((H, W), np.float32)
        out_lab = np.empty((H, W), np.int32)
        _k.apply_noise(
            z, lab, kind, gauss, u_miss, cand, u_fly, a_fly,
            float(self.min_range_m), float(min(self.max_range_m, 1e30)), float(self.missing_fraction),
            float(self.flying_probability), float(self.kinect_coeff), abs(float(intrinsics.fx)) * self.baseline_m,
            float(self.sigma_disp_px), float(self.subpixel_steps), float(self.tof_a_m), float(self.tof_b),
            float(self.tof_edge), float(self.tof_edge_missing), float(intrinsics.cx), float(intrinsics.cy),
            1.0 / max(corner * corner, 1e-12), out, out_lab,
        )
        return out, out_lab

    @staticmethod
    def nearer_neighbour(z: np.ndarray) -> np.ndarray:
        """(H, W) the smallest depth among each pixel's 4 neighbours (inf where none): the near side of a jump."""
        zz = np.where(np.isfinite(z), z, np.inf)
        pad = np.pad(zz, 1, constant_values=np.inf)
        return np.minimum.reduce([pad[:-2, 1:-1], pad[2:, 1:-1], pad[1:-1, :-2], pad[1:-1, 2:]])


_PRESETS = {
    "none": NoiseModel("none"),
    "kinect": NoiseModel("kinect", min_range_m=0.5, max_range_m=5.0, missing_fraction=0.01, flying_probability=0.5),
    "stereo": NoiseModel("stereo", min_range_m=0.35, max_range_m=12.0, missing_fraction=0.03, flying_probability=0.6),
    "tof": NoiseModel("tof", min_range_m=0.2, max_range_m=10.0, missing_fraction=0.005, flying_probability=0.7),
}


def make_noise(name: "str | NoiseModel", **overrides) -> NoiseModel:
    """The noise model ``name`` (none, stereo, kinect, tof) with optional parameter overrides.

    ``make_noise("kinect", flying_probability=0)`` switches flying pixels off; a NoiseModel passes through.
    """
    if isinstance(name, NoiseModel):
        return replace(name, **overrides) if overrides else name
    if name not in _PRESETS:
        raise ValueError(f"name: expected a noise model among {', '.join(NOISE_NAMES)}, got {name!r}")
    try:
        return replace(_PRESETS[name], **overrides)
    except TypeError as exc:
        raise ValueError(f"overrides: {exc}") from None
