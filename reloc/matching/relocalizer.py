"""Relocalization of a submap in a plane map: the orchestration of the matching stages.

``Relocalizer(plane_map, params).locate(submap)`` runs, per round of the incremental input model:

1. submap triplets among the planes fed so far (the first round: ``initial_planes`` representative planes; each
   further round adds the next plane and only tries the triplets containing it);
2. their map candidates through the index (:mod:`reloc.matching.selection`);
3. the transform of each candidate (:func:`reloc.matching._kernels.triplet_transforms`), degenerate ones dropped;
4. verification of each transform against the map with *all* submap planes (Eq. 10-11, scene uniqueness);
5. the decision over every verified hypothesis so far (Eq. 12-14, :mod:`reloc.matching.scoring`); with
   ``tight_decision`` it is taken again over the modes' refined poses, verified at sharper tolerances.

It stops at the first accepted decision; when the planes run out the query is rejected with the last reason.
The winner is refined by least squares over all its matched planes and verified again.
"""

from __future__ import annotations

import math
import re
import time
from dataclasses import dataclass, field, replace

import numpy as np

from reloc.matching import _kernels as K
from reloc.matching.covariance import pose_covariance
from reloc.matching.footprint import MapFootprint
from reloc.matching.index import SURFACE_CELL_M, MapIndex, build_index, horizontal_facing, with_dense_extents
from reloc.matching.params import MatchingParams
from reloc.matching.scoring import (
    FORGIVEN,
    FORGIVEN_WELL_MATCHED,
    Decision,
    decide,
    distinct_from,
    duplicate_stacks,
    explains_enough,
    facet_mask,
    in_conflict,
    largest_area,
    match_quality,
    ratio,
)
from reloc.matching.selection import (
    candidate_triplets,
    gap_bounds,
    order_submap_planes,
    sample_distances,
    sparse_overlays,
    submap_triplets,
    view_distances,
)
from reloc.matching.transform import rotation_from_normal_pairs, translation_from_offsets
from reloc.planes import weakest_direction_support
from reloc.planeset import PlaneSet
from reloc.transforms import check_transform, transform_from_rotation_translation

__all__ = ["RelocResult", "Relocalizer", "Verification", "locate", "support_per_direction", "STAGES"]

RELOCALIZED = "relocalized"
REJECTED = "rejected"
STAGES = ("prepare", "select", "transform", "verify", "decide", "refine")
# Parts of "decide" (their time is included in it): frequency weights (Eq. 12-13), kernel density (Eq. 14), the
# refinement of every mode for the decision over refined poses, the twin probe before accepting (relaxed
# selection, transforms and verification), and the round over the planes not fed that looks for a stronger pose.
SUBSTAGES = ("decide.weights", "decide.density", "decide.tighten", "decide.probe", "decide.stronger")
# A weakly constrained pose slid along its weakest direction (``weak_slide_range_m``): copies from half a metre on
# (twice the suite's 0.25 m for a true pose), an eighth of a metre apart, must each match this many planes fewer.
_SLIDE_MIN_M = 0.5
_SLIDE_STEP_M = 0.125
_SLIDE_MARGIN_PLANES = 2


def too_few_planes_reason(submap_planes: int, map_planes: int, needed: int) -> str:
    """The reason of a query rejected before any search: too few planes on one side (:data:`TOO_FEW_PLANES_RE`)."""
    return f"{submap_planes} submap planes and {map_planes} map planes; at least {needed} needed"


#: Matches :func:`too_few_planes_reason` and nothing else a rejection says (many other reasons name planes).
TOO_FEW_PLANES_RE = re.compile(r"^\d+ submap planes and \d+ map planes; at least \d+ needed$")


@dataclass(frozen=True)
class RelocResult:
    """What a relocalization found and the evidence for it.

    - ``status``: ``"relocalized"`` or ``"rejected"``; ``reason`` says why a query was rejected.
    - ``T_map_cam``: (4, 4) pose of the submap's camera in the map, or None when rejected.
    - ``score``: normalized density of the pose (Eq. 14, 0..1); ``ambiguity_ratio``: score over the best score at a
      different pose (inf when there is none).
    - ``matched``: (M, 2) int64 rows ``(submap plane, map plane)`` (submap indices of the input plane set).
    - ``explained_fraction``: the share of the submap the matched planes explain, each plane weighing the square
      root of its area (planes under ``min_counted_area_m2`` count only when matched).
    - ``counts``: submap planes, planes used, rounds, submap triplets, map triplets looked at (``generated``),
      candidates after selection, degenerate transforms, hypotheses verified, verified hypotheses that passed; when
      relocalized, ``matched_surfaces``: the matched map planes as scene uniqueness counts them (a matched map
      plane adds none when the submap plane matching it also had an already matched map plane among its candidates:
      a door recessed a few centimetres in its wall, with the wall around it), at most ``n_matched``.
    - ``timings_ms``: per stage (:data:`STAGES`), the parts of ``decide`` (:data:`SUBSTAGES`) and ``total``.
    - ``covariance``: (6, 6) covariance of the left perturbation ``(rho, phi)`` of ``T_map_cam`` in the map frame,
      translation first (m^2, rad^2; :func:`reloc.matching.covariance.pose_covariance` over the matched planes), or
      None when rejected.
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
    covariance: np.ndarray | None = None

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
            "covariance": None if self.covariance is None else [[float(f"{x:.6g}") for x in row]
                                                                 for row in self.covariance],
        }


def _rejected(reason: str, counts: dict, timings: dict) -> RelocResult:
    return RelocResult(REJECTED, reason, None, 0.0, math.nan, np.zeros((0, 2), np.int64), 0.0, counts, timings)


@dataclass(frozen=True)
class Verification:
    """What :meth:`Relocalizer.verify` found for H transforms of a submap with S planes.

    Per (hypothesis, submap plane): ``match`` map plane or -1, ``proj`` and ``over`` (Eq. 10-11 ratios), ``state``
    (0 matched, 1 unknown to the map, 2 conflicting with other map surfaces, 3 in known free space, 4 too small to
    count, 5 near a map surface but neither matched nor in conflict: only with a conflict offset above the match
    offset, as in the decision over refined poses; 6 hidden behind a map surface from the submap's cameras, set by
    :meth:`Relocalizer.mark_hidden` in the decision over refined poses), ``free_frac`` (the fraction of an unmatched
    plane's samples in the map's known free space). Per hypothesis: ``n_matched`` matched surfaces (distinct map
    planes, overlapping near-coplanar ones as one: :func:`~reloc.matching._kernels.verify_transforms`), ``explained``
    and ``unknown`` fractions, ``free`` planes in free space, ``passed``. ``evaluated``: (hypothesis, plane) pairs
    looked at.
    """

    match: np.ndarray
    proj: np.ndarray
    over: np.ndarray
    state: np.ndarray
    n_matched: np.ndarray
    explained: np.ndarray
    unknown: np.ndarray
    free: np.ndarray
    passed: np.ndarray
    evaluated: int
    free_frac: np.ndarray


#: A word for each value of :attr:`Verification.state` (what a submap plane is under a pose; see there).
PLANE_STATES = ("matched", "unknown", "conflict", "free", "small", "near", "hidden")


def replace_passed(v: Verification, passed: np.ndarray) -> Verification:
    """``v`` with another ``passed`` mask."""
    return replace(v, passed=passed)


class _Hypotheses:
    """Verified hypotheses that passed, accumulated over the rounds (arrays appended per round)."""

    _FIELDS = ("match", "proj", "over", "state", "free_frac", "n_matched", "explained", "unknown")

    def __init__(self, S: int, forgiven: np.ndarray | None = None, stacks: np.ndarray | None = None):
        # Per submap plane: whether its conflicts with the map are forgiven when a pose's explained fraction is
        # judged, coded as scoring.explains_enough reads it (Relocalizer._forgiven); None when no plane is. And the
        # size of its stack of duplicates, which divides a rival's credit for it (Relocalizer._stacks); None when
        # no plane has a duplicate.
        self.forgiven = forgiven
        self.stacks = stacks
        self.R = np.zeros((0, 3, 3))
        self.t = np.zeros((0, 3))
        self.cand = np.zeros((0, 6), np.int32)
        self.match = np.zeros((0, S), np.int32)
        self.proj = np.zeros((0, S), np.float32)
        self.over = np.zeros((0, S), np.float32)
        self.state = np.zeros((0, S), np.int8)
        self.free_frac = np.zeros((0, S), np.float32)
        self.n_matched = np.zeros(0, np.int32)
        self.explained = np.zeros(0)
        self.unknown = np.zeros(0)
        # Set for the modes of the decision over refined poses: the raw hypothesis each comes from (per mode), and
        # the raw hypotheses of the modes with no least-squares pose (whether or not their raw pose held).
        self.leader: np.ndarray | None = None
        self.unrefined: np.ndarray | None = None
        # With path_test: the raw hypotheses of the modes whose camera path walks through a wall of the map. With
        # conflict_vetoes_rivals (vetoed): of those with a large plane in conflict with the map or hidden behind it
        # that explain too little to win (see Relocalizer._tightened). Neither is a rival.
        self.impossible: np.ndarray | None = None
        self.vetoed: np.ndarray | None = None
        # With hidden_rival_credit (and occlusion): per mode, the share of each plane the map hides from the
        # submap's cameras (:meth:`Relocalizer.mark_hidden`, exact).
        self.hidden_frac: np.ndarray | None = None
        # The modes worked out from these hypotheses for the decisions over refined poses (Relocalizer._tightened).
        self.mode_rows = _ModeRows()

    def blocked(self) -> np.ndarray | None:
        """Per mode of a decision over refined poses, whether it is no rival: its camera path walks through a wall of
        the map, or it is vetoed (:meth:`is_vetoed`); None for raw hypotheses."""
        if self.impossible is None:
            return None
        out = np.isin(self.leader, self.impossible)
        return out if self.vetoed is None else out | np.isin(self.leader, self.vetoed)

    def is_vetoed(self, i: int) -> bool:
        """Whether mode ``i`` of a decision over refined poses is no rival for a large plane in conflict with the
        map or hidden behind it while it explains too little of the submap to win (see
        :meth:`Relocalizer._tightened`)."""
        return self.vetoed is not None and bool(np.isin(self.leader[i], self.vetoed))

    def is_refined(self, i: int) -> bool:
        """Whether mode ``i`` of a decision over refined poses has a least-squares pose (not the raw triplet's)."""
        return bool(self.leader[i] not in self.unrefined)

    def add(self, R, t, cand, v: Verification) -> None:
        keep = v.passed
        self.R = np.concatenate([self.R, R[keep]])
        self.t = np.concatenate([self.t, t[keep]])
        self.cand = np.concatenate([self.cand, cand[keep]])
        for name in self._FIELDS:
            setattr(self, name, np.concatenate([getattr(self, name), getattr(v, name)[keep]]))

    def __len__(self) -> int:
        return int(self.R.shape[0])


def net_matched(hyps) -> np.ndarray:
    """(H,) int: each hypothesis's matched planes less its planes in conflict with the map or hidden behind it."""
    return hyps.n_matched - np.count_nonzero(in_conflict(hyps.state), axis=1)


def stronger_poses(judged, w: int, poses, params: MatchingParams) -> np.ndarray:
    """(len(poses),) bool: which of ``poses`` (refined modes, :class:`_Hypotheses` of a decision over refined poses)
    are stronger than mode ``w`` of ``judged``: at another place (the distinct thresholds), not walking through a
    wall nor vetoed (:meth:`_Hypotheses.blocked`), matching more planes net of those in conflict with the map or
    hidden behind it, and explaining at least as much of the submap. More planes alone is not enough: a twin one
    room along may match a plane or two more of the room's clutter while the true pose explains more of the view."""
    net, net_w = net_matched(poses), net_matched(judged)[w]
    R = np.concatenate([judged.R[w:w + 1], poses.R])
    t = np.concatenate([judged.t[w:w + 1], poses.t])
    out = distinct_from(R, t, 0, params)[1:] & (net > net_w) & (poses.explained >= judged.explained[w])
    blocked = poses.blocked()
    return out if blocked is None else out & ~blocked


def support_per_direction(planes: PlaneSet, match_row: np.ndarray, min_area_m2: float,
                          against: np.ndarray | None = None) -> tuple[float, float, np.ndarray | None]:
    """Area (m^2) of the matched planes (each of at least ``min_area_m2``) that constrain the translation along its
    weakest direction, the area of the planes flagged in ``against`` (S,) bool (each of at least
    ``min_area_m2``, matched or not) along that same direction: evidence against the pose there, which the caller
    takes off the support; and that direction (3,), in the planes' frame (None when no such plane is matched).

    The weakest direction and its support are those of :func:`reloc.planes.weakest_direction_support` over the
    matched planes. A corridor view is pinned along the corridor by a door jamb alone, a few tenths of a square
    metre: one wrong match there would give a confident wrong pose. The caller compares
    the support less the area against with ``min_direction_support_m2`` (0.4 m^2: at 0.5 the relocalization suite
    rejected corridor views pinned by 0.41-0.48 m^2; accepted, the two of them with ToF noise came out 2 and 14 mm
    off). Against, in :meth:`Relocalizer.direction_support`: the planes the map hides from the submap's cameras
    under the pose (``hidden_against_support``), and those in conflict with the map (``conflicts_against_support``).
    A meeting-room view placed in the corridor scene was pinned along the corridor by a cabinet face of 0.70 m^2,
    while the wall of the room it saw through a doorway, 0.59 m^2 and also across the corridor, lay behind the
    corridor's wall.
    """
    large = planes.areas >= min_area_m2
    js = np.flatnonzero((match_row >= 0) & large)
    if len(js) == 0:
        return 0.0, 0.0, None
    n = planes.normals[js]
    a = planes.areas[js]
    e, support = weakest_direction_support(n, a)
    if against is None:
        return support, 0.0, e
    ks = np.flatnonzero(against & large)
    return support, float(planes.areas[ks][np.abs(planes.normals[ks] @ e) >= 0.5].sum()), e


class _ModeRows:
    """The modes of the decisions over refined poses worked out so far for one set of :class:`_Hypotheses`, a row
    per key (the leading hypothesis, and whether the decision weighed several modes); see
    :meth:`Relocalizer._tightened`. The hypotheses only grow, so a row stays true for as long as they live."""

    #: The fields of a :class:`Verification` kept per row.
    VERIFIED = ("match", "proj", "over", "state", "n_matched", "explained", "unknown", "free", "passed", "free_frac")

    def __init__(self):
        self.index: dict[tuple[int, bool], int] = {}
        self.data: dict[str, np.ndarray] = {}

    def add(self, keys: list, rows: dict) -> None:
        """Store ``rows`` (arrays, one row per key of ``keys``), as :meth:`Relocalizer._mode_rows` gives them."""
        n = len(self.index)
        self.index.update((key, n + k) for k, key in enumerate(keys))
        self.data = rows if not self.data else {name: np.concatenate([self.data[name], rows[name]])
                                                for name in self.data}

    def take(self, keys: list) -> dict:
        """The stored rows of ``keys``, in that order."""
        idx = np.array([self.index[key] for key in keys], np.int64)
        return {name: a[idx] for name, a in self.data.items()}


class Relocalizer:
    """Relocalizes submaps in one plane map; the map index is built once, here.

    ``plane_map``: a :class:`~reloc.mapping.PlaneMap` or a :class:`~reloc.planeset.PlaneSet` in the map frame (with
    its gravity). ``brute_force=True`` replaces the index by enumeration of all map triplets (the baseline).
    ``reuse_modes=False`` works out every mode of the decisions over refined poses anew in each round instead of once
    per query (:meth:`_tightened`; the same results, slower: the baseline of ``benchmarks/decision_latency.py``).
    """

    def __init__(self, plane_map, params: MatchingParams | None = None, *, brute_force: bool = False,
                 reuse_modes: bool = True):
        planes = plane_map if isinstance(plane_map, PlaneSet) else getattr(plane_map, "planes", None)
        if not isinstance(planes, PlaneSet):
            raise ValueError(f"plane_map: expected a PlaneMap or PlaneSet, got {type(plane_map).__name__}")
        planes.check_geometry("plane_map")
        self.params = params or MatchingParams()
        self.planes = planes
        self.brute_force = brute_force
        self.reuse_modes = reuse_modes
        free = getattr(plane_map, "free_keys", None) if self.params.free_space else None
        self.index: MapIndex = build_index(planes, self.params, free_keys=free,
                                           free_voxel_m=getattr(plane_map, "free_voxel_m", 0.0))
        if brute_force:
            self.index = with_dense_extents(self.index, planes)
        self._footprint: MapFootprint | None = None

    @property
    def footprint(self) -> MapFootprint | None:
        """The map's footprint (:class:`~reloc.matching.footprint.MapFootprint`: its samples and known free space seen
        from above, grown by ``footprint_margin_m``), built on first use; None for a map without gravity or samples
        (no "above")."""
        if self._footprint is None and self.planes.gravity is not None and len(self.planes.sample_points):
            ix = self.index
            self._footprint = MapFootprint.of_map(self.planes.sample_points, ix.free_keys, ix.free_voxel_m,
                                                  self.planes.gravity, margin_m=self.params.footprint_margin_m)
        return self._footprint

    @property
    def credit_footprint(self) -> MapFootprint | None:
        """The footprint whose outside shares cut a rival's credit in the decision over refined poses, or None when
        they cut nothing (``footprint_rival_credit`` off, no credit for rivals, or no footprint)."""
        p = self.params
        if not (p.footprint_rival_credit and p.hidden_rival_credit and p.optimistic_rivals
                and self._map_knows_free_space):
            return None
        return self.footprint

    @property
    def _map_knows_free_space(self) -> bool:
        """Whether the map holds known free space: only then are rivals credited for planes it knows nothing about
        (``optimistic_rivals``)."""
        return len(self.index.free_keys) > 0

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

    def verify(self, used: PlaneSet, vs_ptr, vs_pts, R, t, cand, *, require_triplet: bool = True,
               tight: bool = False, max_offset_m: float | None = None,
               judge_planes: np.ndarray | None = None) -> Verification:
        """Verify transforms ``(R, t)`` of candidates ``cand`` against the map; see ``verify_transforms``.

        A hypothesis passes (competes) when it could be the truth: its triplet matches, nothing it places lies in the
        map's known free space, it matches at least ``min_matched_planes - 1`` map planes, and it explains at least
        ``min_competitor_fraction`` of the submap counting the planes that land where the map knows nothing. Only a
        competitor that matches ``min_matched_planes`` and itself explains ``min_explained_fraction`` can win the
        decision. So a true pose that the map covers badly (it missed a plane there) still competes with a
        symmetric twin the map happens to cover, and the query is rejected as ambiguous instead of guessed.
        ``tight`` uses the final tolerances (``final_max_angle_rad``, ``final_max_offset_m``) for the refined pose;
        ``max_offset_m`` then replaces the final offset (and caps the projection inlier distance); with
        ``near_decision_offsets`` these decision offsets are set per plane by its distance (``_offset_scale``).
        ``judge_planes`` (indices into ``used``, besides each candidate's three planes) judges only those planes, the
        ones too small to count as well, and lets no plane in known free space fail a hypothesis (its share there is
        still reported): what each of them is under the poses, for :meth:`mark_small_unknown`.
        """
        p = self.params
        H, S = R.shape[0], len(used)
        out = dict(
            match=np.empty((H, S), np.int32), proj=np.empty((H, S), np.float32), over=np.empty((H, S), np.float32),
            state=np.empty((H, S), np.int8), n_matched=np.empty(H, np.int32), explained=np.empty(H),
            unknown=np.empty(H), free=np.empty(H, np.int32), passed=np.empty(H, np.bool_),
            free_frac=np.empty((H, S), np.float32),
        )
        min_matched = max(3, (p.min_matched_planes if p.scene_uniqueness else 3) - 1)
        ix = self.index
        final_offset = p.final_max_offset_m if max_offset_m is None else max_offset_m
        evaluated = K.verify_transforms(
            np.ascontiguousarray(R), np.ascontiguousarray(t), np.ascontiguousarray(cand),
            np.arange(S, dtype=np.int32) if judge_planes is None else np.asarray(judge_planes, dtype=np.int32),
            used.normals, used.offsets, used.centroids, used.areas, vs_ptr, vs_pts, ix.normals, ix.offsets, ix.areas,
            p.min_area_ratio if p.structural_constraints else 0.0, ix.hash_slots, ix.hash_slot_pos, ix.hash_ptr,
            ix.hash_ids, ix.cell_m,
            math.cos(p.final_max_angle_rad if tight else p.match_max_angle_rad),
            final_offset if tight else p.match_max_offset_m,
            min(p.projection_inlier_m, final_offset) if tight else p.projection_inlier_m, p.projection,
            p.min_projection_ratio, p.overlap, p.min_overlap, min_matched, p.min_competitor_fraction,
            p.min_counted_area_m2 if judge_planes is None else 0.0, ix.free_slots, ix.free_voxel_m,
            p.max_free_fraction if judge_planes is None else 1.0, p.free_far_min_fraction,
            require_triplet, max(final_offset, p.decision_conflict_m) if tight else p.match_max_offset_m,
            self._offset_scale(used, final_offset, max(final_offset, p.decision_conflict_m))
            if tight and max_offset_m is not None else np.ones((S, 2)),
            out["match"], out["proj"], out["over"], out["state"], out["n_matched"], out["explained"], out["unknown"],
            out["free"], out["passed"], out["free_frac"],
        )
        return Verification(**out, evaluated=int(evaluated))

    def mark_small_unknown(self, used: PlaneSet, vs_ptr, vs_pts, R, t, cand, v: Verification) -> np.ndarray:
        """Mark the planes of ``used`` too small to count (``v.state`` 4, under ``min_counted_area_m2``) that land where
        the map knows nothing under each pose ``(R[h], t[h])`` (of candidate ``cand[h]``) as unknown to the map (state
        1, changed in place, with their share in known free space in ``v.free_frac``), judged as a plane that counts
        is at the decision's offsets: no map surface facing the same way near it, and no more than
        ``max_free_fraction`` of it in the map's known free space (a small plane there stays too small to count: it
        contradicts no pose, and earns nothing). Returns the (H, S) bool mask of the planes marked.

        For the rivals' credit (``small_rival_credit``): a twin room that the mapping runs covered less completely
        lacks the small faces of its furniture (0.13-0.26 m^2), which the better-covered room's pose matches and
        the twin's pose leaves where its map knows nothing; counted for the winner only, eight of them put a view
        labelled ambiguous 2.1 times ahead of its twin (Kinect, replicate B, meeting_rooms/robot/2).
        """
        p = self.params
        small = v.state == 4
        if not small.any():
            return small
        w = self.verify(used, vs_ptr, vs_pts, R, t, cand, require_triplet=False, tight=True,
                        max_offset_m=p.decision_max_offset_m, judge_planes=np.flatnonzero(small.any(axis=0)))
        small &= (w.state == 1) & (w.free_frac <= p.max_free_fraction)
        v.state[small] = 1
        v.free_frac[small] = w.free_frac[small]
        return small

    def _offset_scale(self, used: PlaneSet, max_offset: float, conflict: float) -> np.ndarray:
        """(S, 2) factors on the decision's match and conflict offsets for each plane of ``used``: with
        ``near_decision_offsets``, offsets raised to follow the sensor's noise at 3 m (``scaled_to_sensor``) come
        down with the noise at the plane's distance from the nearest camera of its window, never below their
        floors (``decision_offset_floor_m``, ``decision_conflict_floor_m``); 1 elsewhere, and for planes smaller
        than ``near_decision_min_area_m2``."""
        p = self.params
        S = len(used)
        scale = np.ones((S, 2))
        if not p.near_decision_offsets or p.noise_depth_power <= 0 or S == 0:
            return scale
        f = (np.minimum(view_distances(used), 3.0) / 3.0) ** p.noise_depth_power
        scale[:, 0] = np.maximum(f, min(1.0, p.decision_offset_floor_m / max_offset))
        scale[:, 1] = np.maximum(f, min(1.0, p.decision_conflict_floor_m / conflict))
        scale[used.areas < p.near_decision_min_area_m2] = 1.0
        return scale

    def mark_hidden(self, used: PlaneSet, vs_ptr, vs_pts, R, t, state: np.ndarray, exact: bool = False,
                    sealed: bool = False) -> np.ndarray:
        """Mark the planes of ``used`` unknown to the map under ``(R, t)`` (``state`` 1, changed in place to 6) that
        the map says the submap's cameras could not have seen (:func:`reloc.matching._kernels.mark_hidden`; the
        cameras are ``used.viewpoints``, or the origin of the latest camera's frame; map surfaces hide from their
        backs too with ``occlusion_from_behind`` and a map that knows its free space; with ``sealed``, a map
        surface hides only what lies where the map never saw past it: no known free space between the two). Returns
        the (H, S) hidden fractions (of a plane not marked, exact only with ``exact``, else a lower bound)."""
        p = self.params
        ix = self.index
        views = used.viewpoints if used.viewpoints is not None else np.zeros((1, 3))
        frac = np.zeros(state.shape, np.float32)
        K.mark_hidden(np.ascontiguousarray(R), np.ascontiguousarray(t), state, used.normals, vs_ptr, vs_pts,
                      np.ascontiguousarray(views), ix.normals, ix.offsets, ix.centroids, ix.radii, ix.bases,
                      ix.surf_ptr, ix.surf_keys, SURFACE_CELL_M, p.occlusion_margin_m, p.occlusion_erode_m,
                      p.occlusion_min_fraction, exact, frac, p.occlusion_from_behind and self._map_knows_free_space,
                      ix.free_slots, ix.free_voxel_m, sealed and self._map_knows_free_space)
        return frac

    def path_blocked(self, used: PlaneSet, R, t) -> np.ndarray:
        """(H,) bool: whether the submap's camera path (``used.viewpoints``, in order) passes through a map surface
        under each pose ``(R[h], t[h])`` (:func:`reloc.matching._kernels.path_blocked`); False without a path."""
        p = self.params
        ix = self.index
        out = np.zeros(len(R), dtype=np.bool_)
        views = used.viewpoints
        if views is None or len(views) < 2 or not len(R):
            return out
        g = self.planes.gravity
        up = np.array([0.0, 0.0, 1.0]) if g is None else -np.asarray(g, dtype=np.float64)  # z up without gravity
        K.path_blocked(np.ascontiguousarray(R), np.ascontiguousarray(t), np.ascontiguousarray(views),
                       p.path_min_step_m, ix.normals, ix.offsets, ix.centroids, ix.radii, ix.bases, ix.surf_ptr,
                       ix.surf_keys, SURFACE_CELL_M, p.path_margin_m, p.path_reach_m, up, out)
        return out

    def refine(self, used: PlaneSet, match_row: np.ndarray, proj_row: np.ndarray) -> np.ndarray | None:
        """Least-squares ``T_map_sub`` over the matched pairs of one hypothesis (weights: area x inlier ratio): the
        rotation from the normals, the translation from the offsets (with ``refine_at_centroids``, each submap plane's
        offset taken at its centroid, so that a pair whose normals differ a little does not pull the translation by
        its distance from the submap frame's origin).

        Robust in two passes: pairs whose normal or centroid disagree with the first solution by more than the
        refinement tolerances (a small plane matched to a neighbour) are dropped and the pose is solved again. When
        the pairs left do not fix the pose, those within ``refine_fallback_max_angle_rad`` of the first solution are
        kept instead (facets of a curved object a few degrees off their map planes). Returns None when fewer than
        three pairs remain or they do not fix the pose.
        """
        p = self.params
        js = np.flatnonzero(match_row >= 0)
        first = self._solve_pairs(used, match_row, proj_row, js)
        if first is None:
            return None
        T, ang, off = first
        keep = (ang <= p.refine_max_angle_rad) & (off <= p.refine_max_offset_m)
        if keep.all():
            return T
        second = self._solve_pairs(used, match_row, proj_row, js[keep])
        if second is not None:
            return second[0]
        if p.refine_fallback_max_angle_rad <= p.refine_max_angle_rad:
            return None
        # The pairs within the angle do not fix the pose (a curved object's facets, a few degrees off the map planes
        # they lie on, were all that held it along one axis): keep those within the fallback angle instead.
        keep = (ang <= p.refine_fallback_max_angle_rad) & (off <= p.refine_max_offset_m)
        if keep.all():
            return T
        third = self._solve_pairs(used, match_row, proj_row, js[keep])
        return None if third is None else third[0]

    def _solve_pairs(self, used: PlaneSet, match_row: np.ndarray, proj_row: np.ndarray, js: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """One least-squares pass of :meth:`refine` over the submap planes ``js``: ``(T_map_sub, angle, offset)``,
        each pair's normal angle and centroid offset under that pose, or None when fewer than three pairs or they do
        not fix the pose."""
        p = self.params
        if len(js) < 3:
            return None
        iz = match_row[js]
        w = used.areas[js] * np.maximum(proj_row[js].astype(np.float64), 1e-3)
        nm, dm = self.index.normals[iz], self.index.offsets[iz]
        R, gap = rotation_from_normal_pairs(used.normals[js], nm, w)
        c_rot = used.centroids[js] @ R.T
        if p.refine_at_centroids:
            # Each pair's offset taken where its submap plane is (its centroid), not at the submap frame's
            # origin, where a normal a degree off its map plane is off by its lever arm.
            d_sub = -np.sum(nm * c_rot, axis=1)
        else:
            d_sub = used.offsets[js]
        t, cond = translation_from_offsets(nm, d_sub, dm, w)
        if gap <= 1e-9 or not cond <= p.max_condition_number:
            return None
        n_map = used.normals[js] @ R.T
        ang = np.arccos(np.clip(np.sum(n_map * nm, axis=1), -1.0, 1.0))
        off = np.abs(np.sum((c_rot + t) * nm, axis=1) + dm)
        return transform_from_rotation_translation(R, t), ang, off

    def _probe_twins(self, used, vs_ptr, vs_pts, facing, distances, sub_ext, hyps, winner_cand, winner_match,
                     counts) -> None:
        """Add to ``hyps`` the verified competitors found with relaxed filters by the winner's submap triplet (the
        first three entries of its candidate row ``winner_cand``) and by the triplets among its ``probe_planes``
        largest matched planes (``winner_match``: its map plane per submap plane, -1 unmatched).

        One triplet is not enough: a twin room whose map lacks one plane of the winner's triplet (a table top the
        mapping run saw only there) is found through the other planes both places share.
        """
        p = self.params
        # Areas and sphere gaps free (a twin the map covers in part has smaller planes farther apart); extents
        # within probe_extent_tolerance_m, not free: on a 2,000-plane map that alone gave 88,000 candidates a probe.
        relaxed = replace(p, extent_tolerance_m=p.probe_extent_tolerance_m, min_area_ratio=0.0, gap_tolerance_m=1e3)
        own = np.ascontiguousarray(np.asarray(winner_cand)[None, :3], dtype=np.int32)
        matched = np.flatnonzero(np.asarray(winner_match) >= 0)
        top = matched[np.argsort(-used.areas[matched], kind="stable")[: p.probe_planes]]
        more, _, ground_more = submap_triplets(used.normals, facing, np.sort(top), 0, p)
        use_ground = bool(p.structural_constraints and facing[own[0, 0]] != 0)
        if len(more) and ground_more == use_ground:
            tri = np.unique(np.concatenate([own, more]), axis=0)
        else:
            tri = own
        face0 = np.ascontiguousarray(facing[tri[:, 0]] if use_ground else np.zeros(len(tri)), dtype=np.int8)
        tri = np.ascontiguousarray(tri, dtype=np.int32)
        cand, generated, _ = candidate_triplets(
            self.index, used.normals, used.areas, tri, face0, gap_bounds(tri, distances, relaxed), sub_ext, use_ground,
            relaxed, brute_force=self.brute_force,
        )
        counts["probe_candidates"] = len(cand)
        if not len(cand):
            return
        H = len(cand)
        R = np.empty((H, 3, 3))
        t = np.empty((H, 3))
        status = np.empty(H, np.int8)
        K.triplet_transforms(cand, used.normals, used.offsets, self.index.normals, self.index.offsets,
                             p.degenerate_min_angle_rad, p.max_condition_number, 2.0 * p.pair_angle_tolerance_rad, R, t,
                             status)
        ok = status == K.TRANSFORM_OK
        if not ok.any():
            return
        R, t, cand = R[ok], t[ok], cand[ok]
        v = self.verify(used, vs_ptr, vs_pts, R, t, cand)
        # Only poses not already among the hypotheses add anything.
        new = v.passed.copy()
        for h in np.flatnonzero(new):
            d = np.linalg.norm(hyps.t - t[h], axis=1)
            if np.any(d < 1e-6):
                new[h] = False
        counts["probe_passed"] = int(new.sum())
        hyps.add(R, t, cand, replace_passed(v, new))

    # -- one query -------------------------------------------------------------------------------------------------

    def _tightened(self, hyps, used: PlaneSet, vs_ptr, vs_pts) -> "_Hypotheses":
        """One hypothesis per mode of ``hyps`` (the ``decision_modes`` best): its leader refined over its matched
        planes (least squares) and verified again at the final tolerances, as the winner will be.

        A look-alike pose matches some planes only within the loose search tolerances (a door 6 cm deep in its niche
        taken for the wall beside it, in a corridor turned end for end); refined and held to
        ``decision_max_offset_m``, it loses them, while the true pose keeps them. Decided on refined poses, the true
        pose stands out where the raw triplet poses tie. With ``path_test``, each mode is also marked when the
        submap's camera path walks through a wall of the map under it (``impossible``; such a mode is no rival).
        With ``conflict_vetoes_rivals``, a mode with a plane of ``max_conflict_area_m2`` or more in conflict with the
        map (that test would turn it away if it won) or hidden behind a map surface, and that explains less than
        ``min_explained_fraction`` of the submap, is no rival either (``vetoed``).

        Each round of the incremental input decides again over all the hypotheses so far, and mostly over the same
        leaders (about three in four on the relocalization suite): what a leader's mode is does not depend on the
        other modes, so it is worked out once per ``hyps`` (:class:`_ModeRows`) and taken from there.
        """
        p = self.params
        order = np.argsort(-match_quality(hyps.n_matched, hyps.explained), kind="stable").astype(np.int64)
        group = np.empty(len(hyps), np.int32)
        leaders = K.group_poses(np.ascontiguousarray(hyps.R), np.ascontiguousarray(hyps.t), order,
                                p.distinct_translation_m, p.distinct_rotation_rad, group)
        leaders = leaders[: p.decision_modes]  # in order of quality: the modes that can still matter
        # Only a rival gets the credit for its small planes: with one mode there is none (a key of its rows).
        several = len(leaders) > 1
        rows = hyps.mode_rows if self.reuse_modes else _ModeRows()
        new = [int(a) for a in leaders if (int(a), several) not in rows.index]
        if new:
            rows.add([(a, several) for a in new],
                     self._mode_rows(hyps, used, vs_ptr, vs_pts, np.asarray(new, np.int64), several))
        m = rows.take([(int(a), several) for a in leaders])
        v = Verification(**{name: m[name] for name in _ModeRows.VERIFIED}, evaluated=0)
        out = _Hypotheses(len(used), hyps.forgiven, hyps.stacks)
        out.add(m["R"], m["t"], hyps.cand[leaders], v)
        out.leader = leaders[v.passed]
        out.unrefined = leaders[~m["refined"]]
        out.impossible = leaders[m["blocked"]]
        out.vetoed = leaders[m["vetoed"]]
        out.hidden_frac = m["hidden"][v.passed] if "hidden" in m else None
        return out

    def _mode_rows(self, hyps, used: PlaneSet, vs_ptr, vs_pts, leaders: np.ndarray, several: bool) -> dict:
        """What :meth:`_tightened` needs of the modes led by the hypotheses ``leaders`` (indices into ``hyps``),
        one row each: the refined pose (``R``, ``t``, whether ``refined``), its verification (the fields of
        :attr:`_ModeRows.VERIFIED`), whether it is ``vetoed`` or its camera path ``blocked``, and with the rivals'
        credit cut for hidden planes, the share of each plane ``hidden`` (read only where the mode passes).
        ``several``: whether the decision weighs more than one mode (the small planes' credit is marked then)."""
        p = self.params
        R = hyps.R[leaders].copy()
        t = hyps.t[leaders].copy()
        refined = np.zeros(len(leaders), dtype=bool)
        for k, a in enumerate(leaders):
            T = self.refine(used, hyps.match[a], hyps.proj[a])
            if T is not None:
                R[k], t[k], refined[k] = T[:3, :3], T[:3, 3], True
        cand = hyps.cand[leaders]
        # Whether a mode competes and may win is judged at the final tolerances, as the winner will be; the
        # evidence it carries (matches, overlaps, conflicts) at the sharper decision offset.
        v = self.verify(used, vs_ptr, vs_pts, R, t, cand, require_triplet=False, tight=True)
        # The largest plane of each mode in conflict at the final tolerances (those of _conclude's test).
        contradicted = largest_area(v.state, used.areas, 2)
        sharp = self.verify(used, vs_ptr, vs_pts, R, t, cand, require_triplet=False, tight=True,
                            max_offset_m=p.decision_max_offset_m)
        v = replace(sharp, n_matched=v.n_matched, explained=v.explained, unknown=v.unknown, passed=v.passed)
        small = None
        if p.small_rival_credit and p.optimistic_rivals and self._map_knows_free_space and several:
            small = self.mark_small_unknown(used, vs_ptr, vs_pts, R, t, cand, v)
        hidden = None
        if p.occlusion:
            # The exact shares cost a full count; only rivals that get credit use them (see :meth:`_decide`).
            exact = p.hidden_rival_credit and p.optimistic_rivals and self._map_knows_free_space
            frac = self.mark_hidden(used, vs_ptr, vs_pts, R, t, v.state, exact=exact)
            hidden = frac if exact else None
            if small is not None:
                # A small plane behind a map surface earns no credit (its hidden share), but counts against no pose:
                # planes too small to count count only when they match.
                v.state[small & (v.state == 6)] = 4
            contradicted = np.maximum(contradicted, largest_area(v.state, used.areas, 6))
        elif p.sealed_rival_credit and p.hidden_rival_credit and p.optimistic_rivals and self._map_knows_free_space:
            # Occlusion off (a noisy sensor's map closes doorways): a rival's credit for a plane still shrinks with
            # the share of it behind a map surface the map never saw past (the outside of the building's outer
            # wall). The states are left alone: only the rivals' credit changes.
            hidden = self.mark_hidden(used, vs_ptr, vs_pts, R, t, v.state.copy(), exact=True, sealed=True)
        footprint = self.credit_footprint
        if footprint is not None:
            # Whatever the sensor: a rival earns no credit for a plane it puts outside the building, beyond every
            # surface and empty space the mapping runs saw (a noisy sensor's map closes the doorways, so the
            # occlusion test is off for it and nothing else says so).
            outside = np.zeros((len(leaders), len(used)))
            if np.any(v.passed):
                outside[v.passed] = footprint.outside_share(vs_ptr, vs_pts, R[v.passed], t[v.passed])
            hidden = outside if hidden is None else np.maximum(hidden, outside)
        vetoed = np.zeros(len(leaders), dtype=bool)
        if p.conflict_vetoes_rivals and p.max_conflict_area_m2 > 0:
            # A mode with a plane of max_conflict_area_m2 or more in conflict with the map (or hidden behind a map
            # surface from the submap's cameras) is contradicted where no more complete map could help it; in
            # conflict, _conclude's test would turn it away if it won. Such a mode that also explains too little
            # of the submap to win is no rival. An office view's true pose lost to a place 2 m along, credited for
            # two walls unknown to the map there (0.49 of the true pose's 0.72) while a third wall, 4.4 m^2, lay off
            # a map wall. A mode that explains enough stays a rival: a quarter turn in the symmetric room that
            # explains 0.91 with one wall in conflict is a twin that a map fused a little differently in each
            # quarter tells apart, not the scene; vetoed, the view (labelled ambiguous) was answered.
            vetoed = (contradicted >= p.max_conflict_area_m2) & (v.explained < p.min_explained_fraction)
        blocked = self.path_blocked(used, R, t) if p.path_test else np.zeros(len(leaders), dtype=bool)
        out = {name: getattr(v, name) for name in _ModeRows.VERIFIED}
        out.update(R=R, t=t, refined=refined, vetoed=vetoed, blocked=blocked)
        if hidden is not None:
            out["hidden"] = hidden
        return out

    def _judge(self, hyps, used: PlaneSet, vs_ptr, vs_pts, min_matched: int, timings: dict,
               trace: dict | None = None):
        """The decision over ``hyps`` and the hypotheses it indexes: with ``tight_decision``, a pose the raw
        hypotheses single out or find ambiguous is decided again over the refined modes (:meth:`_tightened`), the
        modes that could not be refined kept as rivals (:meth:`_unrefined_rival`). ``trace`` (see :meth:`locate`)
        receives both decisions and the hypotheses they were made over."""
        raw_modes = {} if trace is not None else None
        decision = self._decide(hyps, used, min_matched, timings, raw_modes)
        if trace is not None:
            trace.update(raw_decision=decision, raw=hyps, raw_modes=raw_modes, decision=decision, judged=hyps,
                         modes=raw_modes, tight=False)
        if not self.params.tight_decision or decision.best < 0:
            return decision, hyps
        t0 = time.perf_counter()
        tight = self._tightened(hyps, used, vs_ptr, vs_pts)
        timings["decide.tighten"] += (time.perf_counter() - t0) * 1e3
        tight_modes = {} if trace is not None else None
        if not len(tight):
            decision = Decision(False, "no refined pose holds at the final tolerances", -1, 0.0, 0.0, 0)
        else:
            decision = self._decide(tight, used, min_matched, timings, tight_modes)
            if decision.accepted and self.params.unrefined_rivals:
                decision = self._unrefined_rival(hyps, tight, decision)
            if decision.accepted and self.params.equal_rivals:
                decision = self._equal_rival(tight, decision)
        if trace is not None:
            trace.update(decision=decision, judged=tight, modes=tight_modes, tight=True)
        return decision, tight

    def _equal_rival(self, tight, decision: Decision) -> Decision:
        """``decision`` (accepted, over the refined modes ``tight``), or a rejection when another mode, distinct from
        the winner and not walking through a wall, has at least its evidence less ``equal_rival_margin``: matched
        planes, less the planes in conflict, plus the explained fraction.

        The density ranks modes by how many raw hypotheses landed near each, which with a noisy sensor varies by
        chance between poses the submap cannot tell apart: in a stereo view of the square, point-symmetric room
        (replicate A) four quarter turns matched 11-15 planes, explained all of the submap with one or two in
        conflict, and one led the next by 1.66-1.69, past ``min_ambiguity_ratio``.
        """
        w = decision.best
        evidence = match_quality(net_matched(tight), tight.explained)
        rival = distinct_from(tight.R, tight.t, w, self.params)
        rival &= evidence >= evidence[w] - self.params.equal_rival_margin
        blocked = tight.blocked()
        if blocked is not None:
            rival &= ~blocked
        if not rival.any():
            return decision
        a = int(np.flatnonzero(rival)[np.argmax(evidence[rival])])
        away = float(np.linalg.norm(tight.t[a] - tight.t[w]))
        reason = (f"ambiguous: a pose {away:.2f} m from the winner matches {int(tight.n_matched[a])} planes and "
                  f"{tight.explained[a]:.2f} of the submap, with as much evidence")
        return Decision(False, reason, -1, decision.score, decision.runner_up_score, decision.n_modes)

    def _unrefined_rival(self, hyps, tight, decision: Decision) -> Decision:
        """``decision`` (accepted, over the refined modes ``tight`` of ``hyps``), or a rejection when a mode with no
        least-squares pose matched about as well as the winner (within ``unrefined_rival_margin`` of its matched
        planes plus explained fraction, as raw hypotheses).

        Such a mode is held to the decision's offsets at its raw triplet pose, which may be a degree off (stereo's
        planes that disagree by more than the refinement tolerances): it then loses its evidence not because it is
        wrong but because it could not be refined, and the decision cannot tell it from the winner. A stereo corridor
        view whose true pose (7 planes, all of the submap) had no least-squares pose was answered turned end for
        end (6 planes, 5.8 m off) before this test.
        """
        quality = match_quality(hyps.n_matched, hyps.explained)
        rivals = tight.unrefined[tight.unrefined != tight.leader[decision.best]]
        for none in (tight.impossible, tight.vetoed):  # no rivals (see _tightened)
            if none is not None and len(none):
                rivals = rivals[~np.isin(rivals, none)]
        if len(rivals):  # a rival is at another place: a mode within the distinct thresholds of the winner is it
            w = decision.best
            R = np.concatenate([tight.R[w:w + 1], hyps.R[rivals]])
            t = np.concatenate([tight.t[w:w + 1], hyps.t[rivals]])
            rivals = rivals[distinct_from(R, t, 0, self.params)[1:]]
        if not len(rivals):
            return decision
        a = rivals[np.argmax(quality[rivals])]
        if quality[a] < quality[tight.leader[decision.best]] - self.params.unrefined_rival_margin:
            return decision
        return Decision(False, f"ambiguous: a pose matching {int(hyps.n_matched[a])} planes and "
                        f"{hyps.explained[a]:.2f} of the submap, as well as the winner, has no least-squares pose to "
                        "be decided on", -1, decision.score, decision.runner_up_score, decision.n_modes)

    def _forgiven(self, used: PlaneSet, vs_ptr, vs_pts, distances: np.ndarray | None = None) -> np.ndarray | None:
        """Which planes of ``used`` have their conflicts with the map forgiven when a pose's explained fraction is
        judged, coded as :func:`reloc.matching.scoring.explains_enough` reads them: facets of curved clutter
        (:func:`reloc.matching.scoring.facet_mask`, from the ``distances`` between their verification samples,
        computed here when not given) and sparse planes laid over larger ones
        (:func:`reloc.matching.selection.sparse_overlays`) at every pose; a noisy sensor's far planes (from
        ``far_conflict_min_depth_m``) at the poses matching ``far_conflict_min_planes`` or more. None when no rule
        marks a plane."""
        p = self.params
        codes = np.zeros(len(used), dtype=np.int8)
        depths = None
        if p.far_conflict_min_planes > 0 and p.far_conflict_min_depth_m > 0:
            depths = view_distances(used)
            codes[depths >= p.far_conflict_min_depth_m] = FORGIVEN_WELL_MATCHED
        forgiven = sparse_overlays(used, p, depths)
        if p.facet_max_area_m2 > 0:
            if distances is None:
                distances = sample_distances(vs_ptr, vs_pts)
            forgiven |= facet_mask(used.normals, used.centroids, used.areas, distances, p.facet_max_area_m2)
        codes[forgiven] = FORGIVEN
        return codes if codes.any() else None

    def _stacks(self, used: PlaneSet) -> np.ndarray | None:
        """With ``duplicate_credit_once``, the size of each plane's stack of duplicates in ``used``
        (:func:`reloc.matching.scoring.duplicate_stacks`); None when no plane has a duplicate."""
        if not (self.params.duplicate_credit_once and self.params.optimistic_rivals):
            return None
        stacks = duplicate_stacks(used.normals, used.centroids)
        return stacks if np.any(stacks > 1) else None

    def _decide(self, hyps, used: PlaneSet, min_matched: int, timings: dict, modes: dict | None = None) -> Decision:
        """The decision over every hypothesis so far; its weights and density times go to ``timings``, its modes to
        ``modes`` when given (see :func:`decide`)."""
        part: dict = {}
        decision = decide(hyps.R, hyps.t, hyps.match, hyps.over, hyps.n_matched, hyps.explained, self.params,
                          min_matched=min_matched, state=hyps.state, areas=used.areas, free_frac=hyps.free_frac,
                          unknown=hyps.unknown, blocked=hyps.blocked(), hidden_frac=hyps.hidden_frac,
                          optimistic=self._map_knows_free_space, timings_ms=part, modes=modes, forgiven=hyps.forgiven,
                          stacks=hyps.stacks)
        timings["decide.weights"] += part.get("weights", 0.0)
        timings["decide.density"] += part.get("density", 0.0)
        return decision

    def _round(self, used: PlaneSet, vs_ptr, vs_pts, facing, distances, sub_ext, positions: np.ndarray, prev: int,
               counts: dict, timings: dict) -> tuple | None:
        """One round of the incremental input: the submap triplets among the planes ``positions`` that use a plane
        at a position from ``prev`` on (the first ``prev`` were fed before), their candidate map triplets, a
        transform each and its verification. Returns ``(R, t, cand, v)`` for the transforms that were not
        degenerate (``v``: :class:`Verification`), or None."""
        p = self.params
        counts["rounds"] += 1
        t0 = time.perf_counter()
        tri, face0, use_ground = submap_triplets(used.normals, facing, positions, prev, p)
        cand, generated, truncated = candidate_triplets(
            self.index, used.normals, used.areas, tri, face0, gap_bounds(tri, distances, p), sub_ext, use_ground,
            p, brute_force=self.brute_force,
        )
        counts["submap_triplets"] += len(tri)
        counts["generated"] += generated
        counts["candidates"] += len(cand)
        counts["truncated"] += int(truncated)
        t1 = time.perf_counter()
        timings["select"] += (t1 - t0) * 1e3
        H = len(cand)
        if not H:
            return None
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
        if not ok.any():
            return None
        R, t, cand = R[ok], t[ok], cand[ok]
        v = self.verify(used, vs_ptr, vs_pts, R, t, cand)
        counts["verified"] += int(len(R))
        counts["contradicted"] += int(np.count_nonzero(v.free))
        counts["passed"] += int(v.passed.sum())
        timings["verify"] += (time.perf_counter() - t2) * 1e3
        return R, t, cand, v

    def _stronger_rival(self, used: PlaneSet, vs_ptr, vs_pts, facing, distances, sub_ext, prev: int, hyps, judged,
                        decision: Decision, counts: dict, trace: dict | None = None) -> Decision:
        """``decision`` (accepted before the incremental input fed every submap plane), or a rejection when the planes
        not yet fed give a stronger pose elsewhere.

        The rounds stop at the first pose accepted, so a place that only the later planes' triplets reach is never
        weighed. The rest of the planes of at least ``stronger_rival_min_area_m2`` are fed in one more round; its
        hypotheses that match more map planes than any so far are refined and held to the final tolerances
        (:meth:`_tightened`). A pose among them that then matches more planes net of those in conflict than the winner
        and explains at least as much of the submap, at another place and not walking through a wall, turns the answer
        into a rejection: the winner was the first pose found, not the best. A stereo apartment view was answered 6.0
        m off with 7 planes matched and 0.89 of its submap explained, its triplets all drawn from the first five
        planes, one of them a 3 m^2 wall the map lacks at the true pose; the true pose matches 11 and explains 0.91.
        Both tests are needed: on the 27 saved runs (docs/BENCHMARKS.md, "A stronger pose among the planes not fed"),
        more planes alone also turned away 4 true poses, twins one room along or half a turn round matching 1-3 planes
        more but explaining less. Only for a winner that explains less than ``stronger_rival_below_explained``: on
        those runs every winner checked gives the same outcomes, at 0.9 ms more in the median of a run (0.2-1.4).
        Planes under ``stronger_rival_min_area_m2`` are not fed: on a map of 2,000 planes one view's small planes put
        two million map triplets and 0.14 s into the round, 6 ms without them. ``trace`` (a dict) gets ``stronger``,
        ``(poses, i)``: the refined poses of that round and the one the rejection names.
        """
        later = np.arange(prev, len(used))
        later = later[used.areas[later] >= self.params.stronger_rival_min_area_m2]
        if not len(later):
            return decision
        # Its selection, transforms and verification count in decide.stronger, not in the stages of the rounds.
        found = self._round(used, vs_ptr, vs_pts, facing, distances, sub_ext, np.concatenate([np.arange(prev), later]),
                            prev, counts, {"select": 0.0, "transform": 0.0, "verify": 0.0})
        if found is None:
            return decision
        R, t, cand, v = found
        v = replace(v, passed=v.passed & (v.n_matched > hyps.n_matched.max(initial=0)))
        if not v.passed.any():
            return decision
        extra = _Hypotheses(len(used), hyps.forgiven, hyps.stacks)
        extra.add(R, t, cand, v)
        tight = self._tightened(extra, used, vs_ptr, vs_pts)
        if not len(tight):
            return decision
        w = decision.best
        rival = stronger_poses(judged, w, tight, self.params)
        if not rival.any():
            return decision
        a = int(np.flatnonzero(rival)[np.argmax(net_matched(tight)[rival])])
        away = float(np.linalg.norm(tight.t[a] - judged.t[w]))
        if trace is not None:
            trace["stronger"] = (tight, a)
        reason = (f"ambiguous: a pose {away:.2f} m from the winner, found among the planes fed last, matches "
                  f"{int(tight.n_matched[a])} planes against its {int(judged.n_matched[w])}")
        return Decision(False, reason, -1, decision.score, decision.runner_up_score, decision.n_modes)

    def locate(self, submap: PlaneSet, trace: dict | None = None) -> RelocResult:
        """Relocalize ``submap`` (planes in the latest camera frame, with gravity) in the map.

        ``trace``: when a dict, it receives what the result was decided on, for explaining it
        (:func:`reloc.evaluation.explain.explain_query`): ``used`` (the submap planes in the order they were fed,
        as the hypotheses index them) with ``samples`` (their verification samples, ``(vs_ptr, vs_pts)`` as
        :meth:`prepare` gives them), and from the last decision made, ``raw`` (the verified hypotheses) with
        ``raw_decision`` and ``raw_modes``, ``judged`` (the hypotheses of the final decision: one per mode when
        ``tight``, the decision over refined poses, else ``raw`` itself) with ``decision`` and ``modes`` (each
        hypothesis's mode and each mode's score and score as a rival, see :func:`reloc.matching.scoring.decide`;
        empty when no decision was made over them), and when the winner reached the test of its weakest direction,
        ``direction_support``: its support there and the area taken off it (None where nothing is taken off:
        occlusion test or ``hidden_against_support`` off), and when a stronger pose among the planes not fed turned
        the winner away (:meth:`_stronger_rival`), ``stronger``. Tracing changes nothing in the result."""
        if not isinstance(submap, PlaneSet):
            raise ValueError(f"submap: expected a PlaneSet, got {type(submap).__name__}")
        submap.check_geometry("submap")
        p = self.params
        timings = {s: 0.0 for s in (*STAGES, *SUBSTAGES)}
        counts = {
            "submap_planes": len(submap), "planes_used": 0, "rounds": 0, "submap_triplets": 0, "generated": 0,
            "candidates": 0, "degenerate": 0, "verified": 0, "contradicted": 0, "passed": 0, "truncated": 0,
        }
        t_start = time.perf_counter()
        t0 = t_start
        used, order, vs_ptr, vs_pts = self.prepare(submap)
        S = len(used)
        counts["planes_used"] = S
        if trace is not None:
            trace["used"] = used
            trace["samples"] = (vs_ptr, vs_pts)
        # A map without gravity has no horizontal planes to anchor the ground constraint: the submap's go without.
        facing = (horizontal_facing(used, p.ground_tolerance_rad) if self.planes.gravity is not None
                  else np.zeros(S, dtype=np.int8))
        distances = sample_distances(vs_ptr, vs_pts)
        sub_ext = K.trimmed_extents(used.normals, used.offsets, used.sample_ptr,
                                    np.ascontiguousarray(used.sample_points, dtype=np.float64),
                                    p.extent_trim_fraction)
        timings["prepare"] = (time.perf_counter() - t0) * 1e3
        min_matched = p.min_matched_planes if p.scene_uniqueness else 3

        def finish(result: RelocResult) -> RelocResult:
            result.timings_ms["total"] = (time.perf_counter() - t_start) * 1e3
            return result

        if S < min_matched or len(self.index) < 3:
            return finish(_rejected(
                too_few_planes_reason(S, len(self.index), min_matched), counts, timings
            ))
        hyps = _Hypotheses(S, self._forgiven(used, vs_ptr, vs_pts, distances), self._stacks(used))
        coarse = judged = hyps
        decision = Decision(False, "no hypothesis passed verification", -1, 0.0, 0.0, 0)
        rounds = range(min(p.initial_planes, S), S + 1) if p.incremental else [S]
        prev = 0
        for k in rounds:
            found = self._round(used, vs_ptr, vs_pts, facing, distances, sub_ext, np.arange(k), prev, counts, timings)
            prev = k
            if found is None:
                continue
            hyps.add(*found)
            if len(hyps):
                t3 = time.perf_counter()
                decision, judged = self._judge(hyps, used, vs_ptr, vs_pts, min_matched, timings, trace)
                timings["decide"] += (time.perf_counter() - t3) * 1e3
                if decision.accepted:
                    break
        if decision.accepted and p.probe_twins:
            # Before accepting, look for twins the selection filters hid: the same submap triplets matched with
            # only the angle, handedness, ground and area-free tests (a twin room the map covers less completely
            # fails the extent and area filters, but is still a pose that may be the truth).
            t0 = time.perf_counter()
            before = len(hyps)
            self._probe_twins(used, vs_ptr, vs_pts, facing, distances, sub_ext, hyps, judged.cand[decision.best],
                              judged.match[decision.best], counts)
            timings["decide.probe"] += (time.perf_counter() - t0) * 1e3
            if len(hyps) > before:
                decision, judged = self._judge(hyps, used, vs_ptr, vs_pts, min_matched, timings, trace)
            timings["decide"] += (time.perf_counter() - t0) * 1e3
        if (decision.accepted and p.tight_decision and prev < S and p.stronger_rival_below_explained > 0
                and judged.explained[decision.best] < p.stronger_rival_below_explained):
            # The rounds stopped at the first pose accepted: the planes not fed may still hold a stronger pose.
            t0 = time.perf_counter()
            decision = self._stronger_rival(used, vs_ptr, vs_pts, facing, distances, sub_ext, prev, hyps, judged,
                                            decision, counts, trace)
            timings["decide.stronger"] += (time.perf_counter() - t0) * 1e3
            timings["decide"] += (time.perf_counter() - t0) * 1e3
            if trace is not None:
                trace["decision"] = decision
        if not decision.accepted:
            return finish(_rejected(decision.reason, counts, timings))
        return finish(self._conclude(used, order, vs_ptr, vs_pts, judged, judged is not coarse, decision, min_matched,
                                     counts, timings, trace))

    def _conclude(self, used, order, vs_ptr, vs_pts, hyps, tightened: bool, decision: Decision, min_matched: int,
                  counts: dict, timings: dict, trace: dict | None = None) -> RelocResult:
        """The accepted ``decision``'s winner (a hypothesis of ``hyps``; ``tightened``: of the decision over refined
        poses), held to ``min_uncontradicted_planes`` matched planes net of its planes in conflict with the map (with
        ``uncontradicted_net_of_forgiven``, of those whose conflicts are not forgiven), refined by least squares over
        all its matched planes (``refine_iterations`` times, each refined pose verified again), then held to the
        final tolerances, to the explained fraction, to no plane of ``max_conflict_area_m2`` or more in conflict with
        the map and to the support along its weakest direction: the result, relocalized or rejected with the reason."""
        p = self.params
        t0 = time.perf_counter()
        b = decision.best
        if p.scene_uniqueness and p.min_uncontradicted_planes > 0:  # VR-NS turns it off with scene uniqueness
            # Scene uniqueness net of the map's contradictions: a corridor view answered half a turn round (23.9 m
            # off) matched 5 planes with 2 in conflict, and no rival was found. Decided over refined poses, the
            # matches are counted at the final tolerances and the conflicts at the decision's offsets, so a plane
            # matched only within the former and in conflict at the latter counts for nothing.
            # A noisy sensor's planes whose conflicts are forgiven (far planes, facets, sparse overlays; see
            # _forgiven) do not count against the pose (uncontradicted_net_of_forgiven, set by scaled_to_sensor).
            conflicts = in_conflict(hyps.state[b])
            if p.uncontradicted_net_of_forgiven and hyps.forgiven is not None:
                conflicts &= hyps.forgiven == 0
            n, against = int(hyps.n_matched[b]), int(np.count_nonzero(conflicts))
            if n - against < p.min_uncontradicted_planes:
                return _rejected(f"contradicted by the map: {n} planes matched less {against} in conflict with it or "
                                 f"hidden behind it leaves {n - against}, under {p.min_uncontradicted_planes}",
                                 counts, timings)
        cand_row = hyps.cand[b: b + 1]
        match_row, proj_row = hyps.match[b], hyps.proj[b]
        explained = float(hyps.explained[b])
        T = transform_from_rotation_translation(hyps.R[b], hyps.t[b])
        refined, why = p.refine_iterations == 0, ""
        if tightened:
            # Decided over refined poses: the winner's pose is already a least-squares pose; refine on from its
            # matches at the final tolerances (its sharp matches alone may not fix it, e.g. along a corridor).
            v = self.verify(used, vs_ptr, vs_pts, T[None, :3, :3], T[None, :3, 3], cand_row, require_triplet=False,
                            tight=True)
            match_row, proj_row, explained = v.match[0], v.proj[0], float(v.explained[0])
            refined = bool(v.passed[0]) and hyps.is_refined(b)
        for _ in range(p.refine_iterations):
            T_new = self.refine(used, match_row, proj_row)
            if T_new is None:
                why = "no least-squares pose over its matched planes (fewer than 3 agree, or they do not fix it)"
                break
            v = self.verify(used, vs_ptr, vs_pts, T_new[None, :3, :3], T_new[None, :3, 3], cand_row,
                            require_triplet=False)
            if not self._holds(v, min_matched, used.areas, hyps.forgiven):
                why = f"{int(v.n_matched[0])} planes, {v.explained[0]:.2f} of the submap at the refined pose"
                break
            T, match_row, proj_row, explained = T_new, v.match[0], v.proj[0], float(v.explained[0])
            refined = True
        if not refined:
            # The winner's own pose comes from three planes and holds only within the loose search tolerances: a
            # pose 0.14 m and 2.5 deg off matched all five planes of a soak submap whose least-squares pose (2 cm
            # off) no longer matched its smallest plane. A pose the matched planes do not confirm is not accepted.
            timings["refine"] = (time.perf_counter() - t0) * 1e3
            return _rejected(f"refined pose does not verify: {why}", counts, timings)
        # The refined pose must hold at tight tolerances: a true pose is precise to a centimetre, while a look-alike
        # (a desk and monitor in another room's corner) matches only within the loose search tolerances.
        v = self.verify(used, vs_ptr, vs_pts, T[None, :3, :3], T[None, :3, 3], cand_row, require_triplet=False,
                        tight=True)
        timings["refine"] = (time.perf_counter() - t0) * 1e3
        if not self._holds(v, min_matched, used.areas, hyps.forgiven):
            return _rejected(f"pose does not hold at tight tolerances: {int(v.n_matched[0])} planes, "
                             f"{v.explained[0]:.2f} of the submap", counts, timings)
        match_row, explained = v.match[0], float(v.explained[0])
        if p.max_conflict_area_m2 > 0:
            # Evidence against the pose that no amount of evidence for it outweighs: a large plane of the view where
            # the map has a surface facing the same way, but centimetres off it (a wall of an office view placed
            # in the apartment, 2.03 m^2, with 5 planes matched and 0.85 of the view explained).
            worst = float(largest_area(v.state[:1], used.areas, 2)[0])
            if worst >= p.max_conflict_area_m2:
                return _rejected(f"contradicted by the map: a plane of {worst:.2f} m^2 lies off a map surface facing "
                                 f"the same way (at most {p.max_conflict_area_m2} m^2 may)", counts, timings)
        if p.scene_uniqueness and p.min_direction_support_m2 > 0:  # 0: the test is off, with what it takes off
            support, against, weak = self.direction_support(used, vs_ptr, vs_pts, T, v)
            if trace is not None:
                judged = (p.occlusion and p.hidden_against_support) or p.conflicts_against_support
                trace["direction_support"] = (support, against if judged else None)
            if support - against < p.min_direction_support_m2:
                slid = None if weak is None else self.slide_along_weakest(used, vs_ptr, vs_pts, T, weak, cand_row)
                if trace is not None:
                    trace["weak_slide"] = slid
                if slid is None or slid[1] > int(v.n_matched[0]) - _SLIDE_MARGIN_PLANES:
                    less = (f", less {against:.2f} m^2 of planes the map hides from its cameras or in conflict with it"
                            if against else "")
                    peak = ("" if slid is None else f"; slid {slid[0]:+.2f} m along it, it matches {slid[1]} "
                            f"planes against {int(v.n_matched[0])}")
                    timings["refine"] = (time.perf_counter() - t0) * 1e3
                    return _rejected(f"pose weakly constrained: {support:.2f} m^2 of matched planes along its weakest "
                                     f"direction{less} (needs {p.min_direction_support_m2}){peak}", counts, timings)
        # The winner's last checks (the support along its weakest direction, the slides) are part of the stage.
        timings["refine"] = (time.perf_counter() - t0) * 1e3
        js = np.flatnonzero(match_row >= 0)
        matched = np.stack([order[js], match_row[js].astype(np.int64)], axis=1)
        counts["matched_surfaces"] = int(v.n_matched[0])
        t1 = time.perf_counter()
        ids = match_row[js]
        cov, _ = pose_covariance(T, used.normals[js], used.centroids[js], used.covariances[js],
                                 self.planes.normals[ids], self.planes.offsets[ids], self.planes.covariances[ids],
                                 p.covariance_inflation)
        timings["refine"] += (time.perf_counter() - t1) * 1e3
        return RelocResult(RELOCALIZED, "", T, decision.score, ratio(decision.score, decision.runner_up_score),
                           matched, explained, counts, timings, cov)

    def direction_support(self, used: PlaneSet, vs_ptr, vs_pts, T: np.ndarray,
                          v: Verification) -> tuple[float, float, np.ndarray | None]:
        """The support of pose ``T`` (4x4) along its weakest direction (:func:`support_per_direction`, from its
        matches in ``v``, its verification at ``T`` alone), the area taken off it: the planes the map hides from
        the submap's cameras under ``T`` (with ``occlusion`` and ``hidden_against_support``) and those in conflict
        with the map in ``v`` (with ``conflicts_against_support``), and that direction in the submap's frame (None
        when no plane that counts is matched)."""
        p = self.params
        against = None
        if p.occlusion and p.hidden_against_support:
            state = v.state[:1].copy()
            self.mark_hidden(used, vs_ptr, vs_pts, T[None, :3, :3], T[None, :3, 3], state)
            against = state[0] == 6
        if p.conflicts_against_support:
            # A stereo corridor view was placed 0.30 m along the corridor by a face of 2.3 m^2 while a wall of 6.25
            # m^2 facing the same way lay off its map wall: what pins the pose along that direction disagrees.
            conflict = v.state[0] == 2
            against = conflict if against is None else against | conflict
        return support_per_direction(used, v.match[0], p.min_counted_area_m2, against)

    def slide_along_weakest(self, used: PlaneSet, vs_ptr, vs_pts, T: np.ndarray, weak: np.ndarray,
                            cand_row: np.ndarray) -> tuple[float, int] | None:
        """Pose ``T`` (4x4) slid along its weakest direction ``weak`` (3,, in the submap's frame, as
        :meth:`direction_support` gives it) by every multiple of ``_SLIDE_STEP_M`` from ``_SLIDE_MIN_M`` up to
        ``weak_slide_range_m`` each way, each copy verified at the final tolerances: the slide whose copy passes
        with the most matched planes, and that count (-1 when none passes). None when the test is off (a range
        under ``_SLIDE_MIN_M``).

        Planes that do not face along a corridor still end there: a wall at a door niche, the niche's door, a cabinet.
        A pose that its normals leave free along the corridor is still pinned when those extents make it the only
        peak: its copies half a metre along lose planes to the free space and to unmatched ends."""
        steps = np.arange(_SLIDE_MIN_M, self.params.weak_slide_range_m + 1e-9, _SLIDE_STEP_M)
        if len(steps) == 0:
            return None
        e = T[:3, :3] @ weak  # into the map frame
        dx = np.concatenate([-steps[::-1], steps])
        H = len(dx)
        R = np.ascontiguousarray(np.broadcast_to(T[:3, :3], (H, 3, 3)))
        t = T[:3, 3][None, :] + dx[:, None] * e[None, :]
        cand = np.ascontiguousarray(np.broadcast_to(cand_row, (H, cand_row.shape[1])))
        w = self.verify(used, vs_ptr, vs_pts, R, t, cand, require_triplet=False, tight=True)
        n = np.where(w.passed, w.n_matched, -1)
        b = int(np.argmax(n))
        return float(dx[b]), int(n[b])

    def _holds(self, v: Verification, min_matched: int, areas: np.ndarray, forgiven: np.ndarray | None) -> bool:
        """Whether the single pose verified in ``v`` passes, explains enough and matches ``min_matched`` planes
        (``areas``: of the submap planes ``v`` judged; ``forgiven``: which of them have their conflicts forgiven,
        see :meth:`_forgiven`)."""
        return bool(v.passed[0] and explains_enough(v.explained[0], v.unknown[0], v.state[0], self.params,
                                                    v.n_matched[0], areas, v.match[0], forgiven)
                    and v.n_matched[0] >= min_matched)

    def confirm(self, submap: PlaneSet, T_map_cam) -> RelocResult:
        """Whether the map confirms a given pose of ``submap`` (4x4 ``T_map_cam``: a pose predicted by odometry, or
        the ground truth of an evaluation): :meth:`locate` with that pose as its only hypothesis, no search and no
        rival. The pose must verify against the map (its planes matched, none in known free space), win the
        decision alone (explaining enough of the submap, at the sharper offsets of the decision over refined poses),
        and pass the winner's last steps: refined by least squares over its matched planes, held to the final
        tolerances, with no large plane in conflict with the map and enough support along its weakest direction. This
        says whether the submap pins that pose down, not whether another place looks the same.

        Returns a :class:`RelocResult`: relocalized with the refined pose, or rejected with the reason.
        """
        if not isinstance(submap, PlaneSet):
            raise ValueError(f"submap: expected a PlaneSet, got {type(submap).__name__}")
        submap.check_geometry("submap")
        T0 = check_transform(T_map_cam, "T_map_cam")
        p = self.params
        t_start = time.perf_counter()
        timings = {s: 0.0 for s in (*STAGES, *SUBSTAGES)}
        counts = {"submap_planes": len(submap), "planes_used": 0}

        def finish(result: RelocResult) -> RelocResult:
            result.timings_ms["total"] = (time.perf_counter() - t_start) * 1e3
            return result

        t0 = time.perf_counter()
        used, order, vs_ptr, vs_pts = self.prepare(submap)
        S = len(used)
        counts["planes_used"] = S
        timings["prepare"] = (time.perf_counter() - t0) * 1e3
        min_matched = p.min_matched_planes if p.scene_uniqueness else 3
        if S < min_matched or len(self.index) < 3:
            return finish(_rejected(
                too_few_planes_reason(S, len(self.index), min_matched), counts, timings
            ))
        # The verification takes the first three planes of the candidate row first; any three do for a given pose.
        cand = np.array([[0, 1, 2, 0, 0, 0]], dtype=np.int32)
        R, t = np.ascontiguousarray(T0[None, :3, :3]), np.ascontiguousarray(T0[None, :3, 3])
        t0 = time.perf_counter()
        v = self.verify(used, vs_ptr, vs_pts, R, t, cand, require_triplet=False)
        timings["verify"] = (time.perf_counter() - t0) * 1e3
        if not v.passed[0]:
            in_free = f", {int(v.free[0])} in known free space" if v.free[0] else ""
            return finish(_rejected(
                f"pose does not verify: {int(v.n_matched[0])} planes matched{in_free}, {v.explained[0]:.2f} of the "
                "submap explained", counts, timings,
            ))
        hyps = _Hypotheses(S, self._forgiven(used, vs_ptr, vs_pts), self._stacks(used))
        hyps.add(R, t, cand, v)
        t0 = time.perf_counter()
        decision, judged = self._judge(hyps, used, vs_ptr, vs_pts, min_matched, timings)
        timings["decide"] = (time.perf_counter() - t0) * 1e3
        if not decision.accepted:
            return finish(_rejected(decision.reason, counts, timings))
        return finish(self._conclude(used, order, vs_ptr, vs_pts, judged, judged is not hyps, decision, min_matched,
                                     counts, timings))


def locate(plane_map, submap: PlaneSet, params: MatchingParams | None = None) -> RelocResult:
    """One-shot: index ``plane_map`` and relocalize ``submap`` in it (build a :class:`Relocalizer` to reuse it)."""
    return Relocalizer(plane_map, params).locate(submap)
