"""Whether a tracked pose's covariance describes its error: a relocalized pose carried forward by wheel odometry.

Between relocalizations the live loop sends ``TRACKED`` poses: the last relocalized pose moved by the odometry since
(``T_map_ref @ inv(T_odom_ref) @ T_odom_now``). This benchmark drives the simulated firmware's odometry model
(:class:`firmware_bridge.mcu_sim.OdometryModel`: a wheel scale and a gyro scale each about 1 % off, a gyro bias of
0.002 rad/s and random noise, drawn anew for every seed) along the simulated robot's figure-eight
(:class:`firmware_bridge.mcu_sim.PlanarPath`) at 50 Hz. Every ``--every`` seconds a relocalization is taken: the true
pose with an error drawn from a relocalizer's covariance (``--reloc-sigma-mm``, ``--reloc-sigma-deg``, of the order
``pose_covariance.py`` measures). From each, the pose is tracked for each horizon, and its error
``delta = log(T_true T_est^-1)`` (the left perturbation in the map frame, translation first) is normalized by each
covariance: ``delta^T cov^-1 delta``, a chi-square of 6 degrees of freedom when the covariance describes the errors
(95 % below 12.59). Side by side on the same poses:

- ``relocalization only``: the relocalized pose's covariance, held (what a loop that ignored the odometry would say);
- ``odometry's own``: that plus the odometry's own covariance since the reference, as the firmware reports it
  (``P_now - F P_ref F^T``, its random errors only);
- ``ours``: that plus :class:`reloc.live.tracking.OdometryDrift` (``reloc.live.tracking.tracked_covariance``, what
  the live loop sends).

    python benchmarks/tracked_covariance.py [--seeds 40] [--every 10] [--duration 120]
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import git_info, print_table, results_name, write_results  # noqa: E402

HORIZONS_S = (1.0, 2.0, 5.0, 10.0, 20.0, 30.0)
CHI2_6_95, CHI2_6_99 = 12.59, 16.81  # of a chi-square of 6 degrees of freedom
CHI2_3_95 = 7.81  # of 3 degrees of freedom
PLANAR = [0, 1, 5]  # x, y and the rotation about z (the map's up) of the left perturbation
RATE_HZ = 50.0


def _planar(x: float, y: float, yaw: float) -> np.ndarray:
    T = np.eye(4)
    c, s = math.cos(yaw), math.sin(yaw)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:2, 3] = x, y
    return T


def drive(seed: int, duration_s: float):
    """Truth and odometry along the figure-eight: (N,) times, (N, 4, 4) true ``T_map_base``, (N, 3) odometry (x, y,
    yaw), (N, 3, 3) its covariance, and (N,) path length and angle turned by the odometry so far."""
    from firmware_bridge.mcu_sim import OdometryModel, PlanarPath

    path = PlanarPath()
    odo = OdometryModel(seed=seed)
    n = int(duration_s * RATE_HZ) + 1
    ts = np.arange(n) / RATE_HZ
    truth = np.empty((n, 4, 4))
    pose = np.empty((n, 3))
    P = np.empty((n, 3, 3))
    travelled = np.zeros(n)
    turned = np.zeros(n)
    prev = path.state(0.0)[:3]
    truth[0] = path.T_map_base(0.0)
    pose[0] = odo.x, odo.y, odo.yaw
    P[0] = odo.P
    for i in range(1, n):
        now = path.state(ts[i])[:3]
        odo.step(prev, now, 1.0 / RATE_HZ)
        prev = now
        truth[i] = path.T_map_base(ts[i])
        pose[i] = odo.x, odo.y, odo.yaw
        P[i] = odo.P
        travelled[i] = travelled[i - 1] + math.hypot(*(pose[i, :2] - pose[i - 1, :2]))
        turned[i] = turned[i - 1] + abs(math.remainder(pose[i, 2] - pose[i - 1, 2], 2 * math.pi))
    return ts, truth, pose, P, travelled, turned


def odometry_own(P_ref: np.ndarray, P_now: np.ndarray, ref: np.ndarray, now: np.ndarray, yaw_map_odom: float,
                 p_now: np.ndarray) -> np.ndarray:
    """(6, 6) the odometry's reported covariance since the reference, lifted into the map frame's left
    perturbation."""
    F = np.array([[1.0, 0.0, -(now[1] - ref[1])], [0.0, 1.0, now[0] - ref[0]], [0.0, 0.0, 1.0]])
    Q = P_now - F @ P_ref @ F.T
    w, V = np.linalg.eigh(0.5 * (Q + Q.T))
    Q = (V * np.clip(w, 0.0, None)) @ V.T
    c, s = math.cos(yaw_map_odom), math.sin(yaw_map_odom)
    u = np.array([0.0, 0.0, 1.0])
    J = np.zeros((6, 3))
    J[:2, :2] = [[c, -s], [s, c]]
    J[:3, 2] = np.cross(p_now, u)
    J[3:, 2] = u
    return J @ Q @ J.T


def run(args) -> dict:
    from reloc.live.tracking import OdometryDrift, tracked_covariance
    from reloc.transforms import exp_se3, invert, log_se3

    drift = OdometryDrift(args.m_per_m, args.rad_per_m, args.rad_per_rad, args.rad_per_s)
    sig_t, sig_r = args.reloc_sigma_mm * 1e-3, math.radians(args.reloc_sigma_deg)
    cov_ref = np.diag([sig_t**2] * 3 + [sig_r**2] * 3)
    L = np.linalg.cholesky(cov_ref)
    names = ("relocalization only", "odometry's own", "ours")
    nees = {h: {k: [] for k in names} for h in HORIZONS_S}
    planar = {h: {k: [] for k in names} for h in HORIZONS_S}
    err = {h: [] for h in HORIZONS_S}
    sig = {h: {k: [] for k in names} for h in HORIZONS_S}
    up = np.array([0.0, 0.0, 1.0])
    for seed in range(args.seed_base, args.seed_base + args.seeds):
        rng = np.random.default_rng(10_000 + seed)
        ts, truth, pose, P, travelled, turned = drive(seed, args.duration)
        step = int(args.every * RATE_HZ)
        for i0 in range(0, len(ts), step):
            T_ref = exp_se3(-(L @ rng.standard_normal(6))) @ truth[i0]  # T_true = exp(delta) T_est
            T_odom_ref = _planar(*pose[i0])
            yaw_map_odom = math.atan2(T_ref[1, 0], T_ref[0, 0]) - pose[i0, 2]
            for h in HORIZONS_S:
                i = i0 + int(round(h * RATE_HZ))
                if i >= len(ts):
                    continue
                T_est = T_ref @ invert(T_odom_ref) @ _planar(*pose[i])
                delta = log_se3(truth[i] @ invert(T_est))
                p_now = T_est[:3, 3]
                covs = {
                    "relocalization only": cov_ref,
                    "odometry's own": cov_ref + odometry_own(P[i0], P[i], pose[i0], pose[i], yaw_map_odom, p_now),
                    "ours": tracked_covariance(cov_ref, p_now, up, travelled[i] - travelled[i0],
                                               turned[i] - turned[i0], h, drift),
                }
                err[h].append(float(np.linalg.norm(truth[i][:3, 3] - T_est[:3, 3])))
                for k, C in covs.items():
                    nees[h][k].append(float(delta @ np.linalg.solve(C, delta)))
                    d3, C3 = delta[PLANAR], C[np.ix_(PLANAR, PLANAR)]
                    planar[h][k].append(float(d3 @ np.linalg.solve(C3, d3)))
                    sig[h][k].append(math.sqrt(float(np.trace(C[:3, :3]))))
    out = []
    for h in HORIZONS_S:
        for k in names:
            v = np.array(nees[h][k])
            w = np.array(planar[h][k])
            if not len(v):
                continue  # a horizon longer than the drive
            out.append({"horizon_s": h, "covariance": k, "poses": len(v), "mean": float(v.mean()),
                        "median": float(np.median(v)), "within_95": float(np.mean(v <= CHI2_6_95)),
                        "within_99": float(np.mean(v <= CHI2_6_99)), "planar_mean": float(w.mean()),
                        "planar_within_95": float(np.mean(w <= CHI2_3_95)),
                        "position_error_m_median": float(np.median(err[h])),
                        "position_error_m_max": float(np.max(err[h])),
                        "sigma_m_median": float(np.median(sig[h][k]))})
    return {"rows": out, "drift": {k: getattr(drift, k) for k in ("m_per_m", "rad_per_m", "rad_per_rad",
                                                                   "rad_per_s")}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=40, help="odometry models drawn (each with its own errors)")
    ap.add_argument("--seed-base", type=int, default=0, help="the first seed")
    ap.add_argument("--duration", type=float, default=120.0, help="seconds driven per seed")
    ap.add_argument("--every", type=float, default=10.0, help="a relocalization this often (s)")
    ap.add_argument("--reloc-sigma-mm", type=float, default=3.0, help="relocalized position sigma per axis (mm)")
    ap.add_argument("--reloc-sigma-deg", type=float, default=0.05, help="relocalized rotation sigma per axis (deg)")
    ap.add_argument("--name", default="tracked_covariance")
    from reloc.live.tracking import OdometryDrift

    d = OdometryDrift()
    for key in ("m_per_m", "rad_per_m", "rad_per_rad", "rad_per_s"):
        ap.add_argument(f"--{key.replace('_', '-')}", type=float, default=getattr(d, key),
                        help=f"OdometryDrift.{key} (default {getattr(d, key)})")
    args = ap.parse_args(argv)
    results_name(args.name)
    if args.seeds < 1 or args.duration < min(HORIZONS_S) or args.every <= 0:
        ap.error(f"expected --seeds >= 1, --duration >= {min(HORIZONS_S)} s and --every > 0")
    res = run(args)
    print_table(["horizon s", "covariance", "poses", "mean", "< chi2 95%", "< chi2 99%", "planar: mean",
                 "< chi2(3) 95%", "error mm (median / max)", "sigma mm (median)"],
                [[r["horizon_s"], r["covariance"], r["poses"], r["mean"], f"{100 * r['within_95']:.1f} %",
                  f"{100 * r['within_99']:.1f} %", r["planar_mean"], f"{100 * r['planar_within_95']:.1f} %",
                  f"{1e3 * r['position_error_m_median']:.1f} / {1e3 * r['position_error_m_max']:.0f}",
                  f"{1e3 * r['sigma_m_median']:.1f}"] for r in res["rows"]], floatfmt=".3g")
    path = write_results(args.name, params=vars(args), results=res)
    print(f"wrote {path} ({git_info()['commit'][:7]})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
