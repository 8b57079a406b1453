"""Relocalization of a submap in a plane map: the orchestration of the matching stages.

``Relocalizer(plane_map, params).locate(submap)`` runs, per round of the incremental input model:

1. submap triplets among the planes fed so far (the first round: ``initial_planes`` representative planes; each
   further round adds the next plane and only tries the triplets containing it);
2. their map candidates through the index (:mod:`reloc.matching.selection`);
3. the transform of each candidate (:func:`reloc.matching._kernels.triplet_transforms`), degenerate ones dropped;
4. verification of each transform against the map with *all* submap planes (Eq. 10-11, scene uniqueness);
5. the decision over every verified hypothesis so far (Eq. 12-14, :mod:`reloc.matching.scoring`).

It stops at the first accepted decision; when the planes run out the query is rejected with the last reason.
The winner is refined by least squares over all its matched planes and verified again.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from reloc.matching import _kernels as K
from reloc.matching.index import MapIndex, build_index, horizontal_facing
from reloc.matching.params import MatchingParams
from reloc.matching.scoring import Decision, decide, ratio
from reloc.matching.selection import (
    candidate_triplets,
    gap_bounds,
    order_submap_planes,
    sample_distances,
    submap_triplets,
)
from reloc.matching.transform import rotation_from_normal_pairs, translation_from_offsets
from reloc.planeset import PlaneSet
from reloc.transforms import transform_from_rotation_translation

__all__ = ["RelocResult", "Relocalizer", "locate", "STAGES"]

RELOCALIZED = "relocalized"
REJECTED = "rejected"
STAGES = ("prepare", "select", "transform", "verify", "decide", "refine")


@dataclass(frozen=True)
class RelocResult:
    """What a relocalization found and the evidence for it.

    - ``status``: ``"relocalized"`` or ``"rejected"``; ``reason`` says why a query was rejected.
    - ``T_map_cam``: (4, 4) pose of the submap's camera in the map, or None when rejected.
    - ``score``: normalized density of the pose (Eq. 14, 0..1); ``ambiguity_ratio``: score over the best score at a
      different pose (inf when there is none).
    - ``matched``: (M, 2) int64 rows ``(submap plane, map plane)`` (submap indices of the input plane set).
    - ``explained_fraction``: matched submap area over the submap area used.
    - ``counts``: submap planes, planes used, rounds, submap triplets, map triplets looked at (``generated``),
      candidates after selection, degenerate transforms, hypotheses verified, verified hypotheses that passed.
    - ``timings_ms``: per stage (:data:`STAGES`) and ``total``.
    """

    status: str
    reason: str
    T_map_cam: np.ndarray | None
    score: float
    ambiguity_ratio: float
    matched: np.ndarray
    explained_fraction: float
    counts: dict = field(default_factory=dict)
    timings_ms: dict = field(default_factory=dict)

    @property
    def relocalized(self) -> bool:
        return self.status == RELOCALIZED

    @property
    def n_matched(self) -> int:
        return int(len(np.unique(self.matched[:, 1]))) if len(self.matched) else 0

    def to_dict(self) -> dict:
        """JSON-ready dict (the pose as a 4x4 nested list or None)."""
        return {
            "status": self.status,
            "reason": self.reason,
            "T_map_cam": None if self.T_map_cam is None else np.round(self.T_map_cam, 9).tolist(),
            "score": round(float(self.score), 6),
            "ambiguity_ratio": None if not math.isfinite(self.ambiguity_ratio) else round(self.ambiguity_ratio, 4),
            "matched_planes": self.n_matched,
            "matched": self.matched.tolist(),
            "explained_fraction": round(float(self.explained_fraction), 4),
            "counts": dict(self.counts),
            "timings_ms": {k: round(float(v), 4) for k, v in self.timings_ms.items()},
        }


def _rejected(reason: str, counts: dict, timings: dict) -> RelocResult:
    return RelocResult(REJECTED, reason, None, 0.0, math.nan, np.zeros((0, 2), np.int64), 0.0, counts, timings)


class _Hypotheses:
    """Verified hypotheses accumulated over the rounds (arrays appended per round)."""

    def __init__(self, S: int):
        self.R = np.zeros((0, 3, 3))
        self.t = np.zeros((0, 3))
        self.cand = np.zeros((0, 6), np.int32)
        self.match = np.zeros((0, S), np.int32)
        self.proj = np.zeros((0, S), np.float32)
        self.over = np.zeros((0, S), np.float32)
        self.nmatched = np.zeros(0, np.int32)
        self.explained = np.zeros(0)

    def add(self, keep, R, t, cand, match, proj, over, nmatched, explained) -> None:
        self.R = np.concatenate([self.R, R[keep]])
        self.t = np.concatenate([self.t, t[keep]])
        self.cand = np.concatenate([self.cand, cand[keep]])
        self.match = np.concatenate([self.match, match[keep]])
        self.proj = np.concatenate([self.proj, proj[keep]])
        self.over = np.concatenate([self.over, over[keep]])
        self.nmatched = np.concatenate([self.nmatched, nmatched[keep]])
        self.explained = np.concatenate([self.explained, explained[keep]])

    def __len__(self) -> int:
        return int(self.R.shape[0])


class Relocalizer:
    """Relocalizes submaps in one plane map; the map index is built once, here.

    ``plane_map``: a :class:`~reloc.mapping.PlaneMap` or a :class:`~reloc.planeset.PlaneSet` in the map frame (with
    its gravity). ``brute_force=True`` replaces the index by enumeration of all map triplets (the baseline).
    """

    def __init__(self, plane_map, params: MatchingParams | None = None, *, brute_force: bool = False):
        planes = plane_map if isinstance(plane_map, PlaneSet) else getattr(plane_map, "planes", None)
        if not isinstance(planes, PlaneSet):
            raise ValueError(f"plane_map: expected a PlaneMap or PlaneSet, got {type(plane_map).__name__}")
        self.params = params or MatchingParams()
        self.planes = planes
        self.brute_force = brute_force
        self.index: MapIndex = build_index(planes, self.params)

    # -- public steps --------------------------------------------------------------------------------------------

    def prepare(self, submap: PlaneSet) -> tuple[PlaneSet, np.ndarray, np.ndarray, np.ndarray]:
        """The planes used (incremental order), their original indices, verification samples (CSR)."""
        order = order_submap_planes(submap, self.params)
        used = submap.subset(order)
        m = self.params.verify_samples_per_plane
        pts = np.ascontiguousarray(used.sample_points, dtype=np.float64)
        ptr = used.sample_ptr
        # Planes without samples verify with their centroid.
        if np.any(np.diff(ptr) == 0):
            pieces, new_ptr = [], [0]
            for j in range(len(used)):
                s = pts[ptr[j]: ptr[j + 1]]
                s = used.centroids[j: j + 1] if len(s) == 0 else s
                pieces.append(s)
                new_ptr.append(new_ptr[-1] + len(s))
            pts, ptr = np.ascontiguousarray(np.concatenate(pieces)), np.array(new_ptr, np.int64)
        vs_ptr = np.empty(len(used) + 1, np.int64)
        vs_pts = np.empty((len(used) * m, 3))
        n = K.farthest_point_samples(pts, ptr, m, vs_ptr, vs_pts)
        return used, order, vs_ptr, np.ascontiguousarray(vs_pts[:n])

    def verify(self, used: PlaneSet, vs_ptr, vs_pts, R, t, cand):
        """Verify transforms ``(R, t)`` of candidates ``cand`` against the map; see ``verify_transforms``."""
        p = self.params
        H, S = R.shape[0], len(used)
        out_match = np.empty((H, S), np.int32)
        out_proj = np.empty((H, S), np.float32)
        out_over = np.empty((H, S), np.float32)
        out_n = np.empty(H, np.int32)
        out_e = np.empty(H)
        out_pass = np.empty(H, np.bool_)
        min_matched = p.min_matched_planes if p.scene_uniqueness else 3
        ix = self.index
        evaluated = K.verify_transforms(
            np.ascontiguousarray(R), np.ascontiguousarray(t), np.ascontiguousarray(cand), np.arange(S, dtype=np.int32),
            used.normals, used.offsets, used.centroids, used.areas, vs_ptr, vs_pts, ix.normals, ix.offsets, ix.areas,
            p.min_area_ratio if p.structural_constraints else 0.0, ix.hash_keys, ix.hash_ptr, ix.hash_ids, ix.cell_m, math.cos(p.match_max_angle_rad), p.match_max_offset_m,
            p.projection_inlier_m, p.projection, p.min_projection_ratio, p.overlap, p.min_overlap, min_matched,
            p.min_explained_fraction, out_match, out_proj, out_over, out_n, out_e, out_pass,
        )
        return out_match, out_proj, out_over, out_n, out_e, out_pass, int(evaluated)

    def refine(self, used: PlaneSet, match_row: np.ndarray, proj_row: np.ndarray) -> np.ndarray | None:
        """Least-squares ``T_map_sub`` over all matched pairs of one hypothesis (weights: area x inlier ratio)."""
        js = np.flatnonzero(match_row >= 0)
        if len(js) < 3:
            return None
        iz = match_row[js]
        w = used.areas[js] * np.maximum(proj_row[js].astype(np.float64), 1e-3)
        R, gap = rotation_from_normal_pairs(used.normals[js], self.index.normals[iz], w)
        t, cond = translation_from_offsets(self.index.normals[iz], used.offsets[js], self.index.offsets[iz], w)
        if gap <= 1e-9 or not cond <= self.params.max_condition_number:
            return None
        return transform_from_rotation_translation(R, t)

    # -- one query -------------------------------------------------------------------------------------------------

    def locate(self, submap: PlaneSet) -> RelocResult:
        """Relocalize ``submap`` (planes in the latest camera frame, with gravity) in the map."""
        if not isinstance(submap, PlaneSet):
            raise ValueError(f"submap: expected a PlaneSet, got {type(submap).__name__}")
        p = self.params
        timings = {s: 0.0 for s in STAGES}
        counts = {
            "submap_planes": len(submap), "planes_used": 0, "rounds": 0, "submap_triplets": 0, "generated": 0,
            "candidates": 0, "degenerate": 0, "verified": 0, "passed": 0, "truncated": 0,
        }
        t_start = time.perf_counter()
        t0 = t_start
        used, order, vs_ptr, vs_pts = self.prepare(submap)
        S = len(used)
        counts["planes_used"] = S
        facing = horizontal_facing(used, p.ground_tolerance_rad)
        distances = sample_distances(vs_ptr, vs_pts)
        timings["prepare"] = (time.perf_counter() - t0) * 1e3
        min_matched = p.min_matched_planes if p.scene_uniqueness else 3

        def finish(result: RelocResult) -> RelocResult:
            result.timings_ms["total"] = (time.perf_counter() - t_start) * 1e3
            return result

        if S < min_matched or len(self.index) < 3:
            return finish(_rejected(
                f"{S} submap planes and {len(self.index)} map planes; at least {min_matched} needed", counts, timings
            ))
        hyps = _Hypotheses(S)
        decision = Decision(False, "no hypothesis passed verification", -1, 0.0, 0.0, 0)
        rounds = range(min(p.initial_planes, S), S + 1) if p.incremental else [S]
        prev = 0
        for k in rounds:
            counts["rounds"] += 1
            t0 = time.perf_counter()
            tri, face0, use_ground = submap_triplets(used.normals, facing, np.arange(k), prev, p)
            prev = k
            cand, generated, truncated = candidate_triplets(
                self.index, used.normals, used.areas, tri, face0, gap_bounds(tri, distances, p), use_ground, p,
                brute_force=self.brute_force,
            )
            counts["submap_triplets"] += len(tri)
            counts["generated"] += generated
            counts["candidates"] += len(cand)
            counts["truncated"] += int(truncated)
            t1 = time.perf_counter()
            timings["select"] += (t1 - t0) * 1e3
            H = len(cand)
            if H:
                R = np.empty((H, 3, 3))
                t = np.empty((H, 3))
                status = np.empty(H, np.int8)
                K.triplet_transforms(
                    cand, used.normals, used.offsets, self.index.normals, self.index.offsets,
                    p.degenerate_min_angle_rad, p.max_condition_number, 2.0 * p.pair_angle_tolerance_rad, R, t, status,
                )
                ok = status == K.TRANSFORM_OK
                counts["degenerate"] += int(H - ok.sum())
                t2 = time.perf_counter()
                timings["transform"] += (t2 - t1) * 1e3
                if ok.any():
                    R, t, cand = R[ok], t[ok], cand[ok]
                    match, proj, over, nmatched, explained, passed, _ = self.verify(used, vs_ptr, vs_pts, R, t, cand)
                    counts["verified"] += int(len(R))
                    counts["passed"] += int(passed.sum())
                    hyps.add(passed, R, t, cand, match, proj, over, nmatched, explained)
                t3 = time.perf_counter()
                timings["verify"] += (t3 - t2) * 1e3
                if passed_any := (len(hyps) > 0):
                    decision = decide(hyps.R, hyps.t, hyps.match, hyps.over, hyps.nmatched, hyps.explained, p)
                timings["decide"] += (time.perf_counter() - t3) * 1e3
                if passed_any and decision.accepted:
                    break
        if not decision.accepted:
            return finish(_rejected(decision.reason, counts, timings))
        # Refine the winner over all its matched planes, then verify and refine again.
        t0 = time.perf_counter()
        b = decision.best
        match_row, proj_row = hyps.match[b], hyps.proj[b]
        explained = float(hyps.explained[b])
        T = transform_from_rotation_translation(hyps.R[b], hyps.t[b])
        for _ in range(p.refine_iterations):
            T_new = self.refine(used, match_row, proj_row)
            if T_new is None:
                break
            m, pr, _, _, ex, ok, _ = self.verify(used, vs_ptr, vs_pts, T_new[None, :3, :3], T_new[None, :3, 3],
                                                 hyps.cand[b: b + 1])
            if not ok[0]:
                break
            T, match_row, proj_row, explained = T_new, m[0], pr[0], float(ex[0])
        timings["refine"] = (time.perf_counter() - t0) * 1e3
        js = np.flatnonzero(match_row >= 0)
        matched = np.stack([order[js], match_row[js].astype(np.int64)], axis=1)
        return finish(RelocResult(
            RELOCALIZED, "", T, decision.score, ratio(decision.score, decision.runner_up_score), matched, explained,
            counts, timings,
        ))


def locate(plane_map, submap: PlaneSet, params: MatchingParams | None = None) -> RelocResult:
    """One-shot: index ``plane_map`` and relocalize ``submap`` in it (build a :class:`Relocalizer` to reuse it)."""
    return Relocalizer(plane_map, params).locate(submap)
