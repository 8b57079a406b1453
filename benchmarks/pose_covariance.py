"""Whether a relocalized pose's covariance describes its error, on the simulated suite of reloc_accuracy.py.

For every positive query answered within 0.25 m and 5 deg of the truth, the error ``delta = log(T_true T_est^-1)``
(the left perturbation in the map frame, translation first, as the covariance is stated) is normalized by each
covariance: ``delta^T cov^-1 delta``. For a covariance that describes the errors this is a chi-square of 6 degrees of
freedom: mean 6, 95 % below 12.59, 99 % below 16.81. Side by side on the same poses:

- ``fit only``: the information of the matched pairs from the plane fits' covariances alone (the baseline: what
  the planes claim);
- ``every pair in full``: that, times the variance factor of the pairs' own residuals at the pose and times
  ``covariance_inflation``, every pair weighed in full (the first version, 28162bc);
- ``ours``: the relocalizer's covariance (the same, with a pair whose squared residual exceeds 4x the median pair's
  weighed as if it were 4x).

    python benchmarks/pose_covariance.py [--noise kinect,tof,stereo] [--prepared DIR] [--query-seed N --map-seed N]

``--prepared DIR`` takes the suites saved by ``reloc_accuracy.py --save-prepared DIR`` (``DIR/extraction_<noise>``),
given the same suite options (seeds, scenes, sizes: a suite saved with other ones is refused, naming them);
without it each suite is prepared here (minutes a noise model; ``--quick`` for a small one).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import git_info, print_table, quick_presets, write_results  # noqa: E402

CHI2_6_99 = 16.81  # 99 % of a chi-square of 6 degrees of freedom (95 %: reloc.evaluation.metrics.CHI2_6_95)


def normalized_errors(prepared, params) -> dict:
    """Per covariance (fit only, every pair in full, ours) the normalized squared errors of the suite's true poses,
    with the translation errors and the covariances' translation sigmas (sqrt of the trace, m)."""
    from reloc.evaluation.metrics import TP_MAX_ROTATION_DEG, TP_MAX_TRANSLATION_M, covariance_check
    from reloc.matching.covariance import pose_covariance
    from reloc.transforms import invert, log_se3, pose_error

    out = {k: [] for k in ("fit only", "every pair in full", "ours")}
    sig = {k: [] for k in out}
    errors, names = [], []
    for scene, queries in prepared.queries.items():
        reloc = prepared.relocalizer(scene, params)
        planes = reloc.planes
        for q in queries:
            if q.scene != scene:
                continue
            res = reloc.locate(q.submap)
            if not res.relocalized:
                continue
            t_err, r_err = pose_error(res.T_map_cam, q.T_world_cam)
            if t_err > TP_MAX_TRANSLATION_M or r_err > TP_MAX_ROTATION_DEG or res.covariance is None:
                continue
            s = q.submap
            j, i = res.matched[:, 0], res.matched[:, 1]
            full, s0sq = pose_covariance(res.T_map_cam, s.normals[j], s.centroids[j], s.covariances[j],
                                         planes.normals[i], planes.offsets[i], planes.covariances[i],
                                         params.covariance_inflation, outlier_factor=math.inf)
            fit = full / (s0sq * params.covariance_inflation)
            for key, cov in (("fit only", fit), ("every pair in full", full), ("ours", res.covariance)):
                nees, sigma_t = covariance_check(res.T_map_cam, q.T_world_cam, cov)
                out[key].append(nees)
                sig[key].append(sigma_t)
            errors.append(float(np.linalg.norm(log_se3(q.T_world_cam @ invert(res.T_map_cam))[:3])))
            names.append(q.name)
    return {"nees": out, "sigma_t_m": sig, "error_t_m": errors, "queries": names}


def summary(nees: list[float], sigma: list[float], errors: list[float]) -> dict:
    from reloc.evaluation.metrics import CHI2_6_95

    e = np.asarray(nees)
    if len(e) == 0:
        return {"poses": 0}
    return {"poses": len(e), "mean": float(e.mean()), "median": float(np.median(e)),
            "within_95": float(np.mean(e < CHI2_6_95)), "within_99": float(np.mean(e < CHI2_6_99)),
            "median_sigma_t_m": float(np.median(sigma)), "p90_sigma_t_m": float(np.percentile(sigma, 90)),
            "max_sigma_t_m": float(np.max(sigma)), "median_error_t_m": float(np.median(errors)),
            "rms_error_t_m": float(np.sqrt(np.mean(np.square(errors))))}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--noise", default="kinect,tof,stereo", help="Noise models, comma-separated.")
    ap.add_argument("--queries", type=int, default=10, help="Positive queries per trajectory kind and scene.")
    ap.add_argument("--map-frames", type=int, default=3000, help="Frames of each mapping trajectory.")
    ap.add_argument("--query-seed", type=int, default=None, help="Seed of the queries (default: the suite's).")
    ap.add_argument("--map-seed", type=int, default=None, help="Seed of the maps (default: the suite's).")
    ap.add_argument("--scenes", default=None, help="Scenes, comma-separated (default: the suite's six).")
    ap.add_argument("--prepared", type=Path, default=None,
                    help="Directory of suites saved by reloc_accuracy.py --save-prepared (extraction_<noise>).")
    ap.add_argument("--quick", action="store_true", help="A small suite (Kinect noise, two scenes, 800-frame maps).")
    ap.add_argument("--name", default="pose_covariance", help="Results file name (benchmarks/results/NAME.json).")
    args = ap.parse_args()
    if args.quick:
        quick_presets(ap, args, {"noise": "kinect", "queries": 3, "map_frames": 800, "scenes": "living_room,office"})

    from reloc._numba import warm_up
    from reloc.evaluation.prepared_io import PreparedSuiteError, built_with, load_prepared, mismatch
    from reloc.evaluation.suite import SCENES, prepare_suite, suite_spec
    from reloc.mapping import MappingParams
    from reloc.matching import MatchingParams

    warm_up(("reloc.matching._kernels", "reloc.mapping._kernels", "reloc.extraction.pipeline"))
    params = MatchingParams()
    scenes = tuple(args.scenes.split(",")) if args.scenes else SCENES
    seeds = {k: v for k, v in (("query_seed", args.query_seed), ("map_seed", args.map_seed)) if v is not None}
    rows, results = [], {}
    here = git_info()
    for noise in args.noise.split(","):
        t0 = time.perf_counter()
        spec = suite_spec(noise, scenes=scenes, queries=args.queries, map_frames=args.map_frames, **seeds)
        if args.prepared is not None:
            where = args.prepared / f"extraction_{noise}"
            try:
                prepared, meta = load_prepared(where)
            except PreparedSuiteError as exc:
                ap.error(f"--prepared: {exc}")
            # The suite asked for (seeds, scenes, sizes) must be the one saved: a replicate's suite loaded without
            # its seeds would be reported as the tuned suite.
            problems = mismatch(prepared, meta, spec, built_with(spec))
            if problems:
                ap.error(f"--prepared: {where} holds another suite than this command asks for: {'; '.join(problems)}")
            if meta.get("commit") != here["commit"]:
                print(f"note: {where} was prepared at commit {meta.get('commit')}")
        else:
            prepared = prepare_suite(spec, MappingParams())
        prep_s = time.perf_counter() - t0
        got = normalized_errors(prepared, params)
        results[noise] = {"prepare_s": prep_s, "queries": got["queries"], "error_t_m": got["error_t_m"],
                          "nees": got["nees"], "summary": {}}
        for key in got["nees"]:
            s = summary(got["nees"][key], got["sigma_t_m"][key], got["error_t_m"])
            results[noise]["summary"][key] = s
            rows.append([noise, key, s["poses"], s.get("mean"), s.get("median"), s.get("within_95"),
                         s.get("within_99"), 1e3 * s.get("median_sigma_t_m", math.nan),
                         1e3 * s.get("p90_sigma_t_m", math.nan), 1e3 * s.get("max_sigma_t_m", math.nan),
                         1e3 * s.get("rms_error_t_m", math.nan)])
    print_table(["noise", "covariance", "poses", "mean", "median", "< chi2 95%", "< chi2 99%", "sigma_t mm (median)",
                 "p90", "max", "error_t mm (rms)"], rows, floatfmt=".3g",
                title="delta^T cov^-1 delta of the true poses (a chi-square of 6 dof: mean 6, median 5.35)")
    path = write_results(args.name, params={**vars(args), "prepared": str(args.prepared) if args.prepared else None,
                                            "covariance_inflation": params.covariance_inflation},
                         results=results)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
