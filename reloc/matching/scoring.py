"""From verified hypotheses to one decision: frequency weights (Eq. 12-13), kernel density (Eq. 14), acceptance.

Each verified hypothesis ``a`` is a pose ``v_a = T_map_sub`` with its matched plane pairs ``(i, j)`` and their
overlaps ``o(i, j)``. The paper's intent for Eq. 12-13 is that a plane pair weighs less the more often it appears
across the hypotheses: here a submap plane j that is matched at ``f_j`` distinct poses (modes) contributes
``o(i, j) / f_j`` to the weight ``w_a = sum o(i, j) w_a(i, j)`` of every hypothesis using it, so planes that fit
everywhere (a floor, a generic wall) count little and distinctive planes count fully. The density
``P(x) = 1/Z sum_a w_a exp(-xi^T I xi)``, ``xi = log(v_x^-1 v_a)``, ``Z = sum_a w_a`` (Eq. 14) is evaluated at every
candidate pose; the best pose wins only when its density clears ``min_score`` and is at least
``min_ambiguity_ratio`` times the density of the best pose at a *different* place (farther than the distinct
thresholds). Otherwise the query is rejected as ambiguous: identical rooms and symmetric rooms are not guessed.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from reloc.matching import _kernels as K
from reloc.matching.params import MatchingParams

__all__ = [
    "Decision", "frequency_weights", "pose_density", "decide", "distinct_from", "explains_enough", "facet_mask",
    "in_conflict", "largest_area", "match_quality", "duplicate_stacks", "FORGIVEN", "FORGIVEN_WELL_MATCHED",
]

#: Two planes that touch (verification samples within FACET_TOUCH_M) with normals FACET_MIN_ANGLE_DEG to
#: FACET_MAX_ANGLE_DEG apart, bending away from each other, are facets of one curved surface (see
#: :func:`facet_mask`). A room's corner bends the other way, a door jamb meets its wall at 90 deg.
FACET_MIN_ANGLE_DEG = 8.0
FACET_MAX_ANGLE_DEG = 60.0
FACET_TOUCH_M = 0.15
#: Two submap planes whose centroids lie within DUPLICATE_MAX_DISTANCE_M of each other, normals within
#: DUPLICATE_MAX_ANGLE_DEG (the values of map fusion's ``fuse_max_offset_m`` and ``fuse_max_angle_deg``), are one
#: surface fitted twice (see :func:`duplicate_stacks`).
DUPLICATE_MAX_DISTANCE_M = 0.03
DUPLICATE_MAX_ANGLE_DEG = 8.0


@dataclass(frozen=True)
class Decision:
    accepted: bool
    reason: str
    best: int  # index of the winning hypothesis, -1 when there is none
    score: float  # normalized density at the best pose (0..1)
    runner_up_score: float  # normalized density at the best different pose (0 when there is none)
    n_modes: int


def distinct_from(R: np.ndarray, t: np.ndarray, a: int, params: MatchingParams) -> np.ndarray:
    """(H,) bool: poses farther than the distinct thresholds from pose ``a``."""
    dt = np.linalg.norm(t - t[a], axis=1)
    cos = 0.5 * (np.einsum("hij,ij->h", R, R[a]) - 1.0)
    ang = np.arccos(np.clip(cos, -1.0, 1.0))
    return (dt > params.distinct_translation_m) | (ang > params.distinct_rotation_rad)


def in_conflict(state: np.ndarray) -> np.ndarray:
    """Where a plane's verification ``state`` is evidence against its pose: in conflict with map surfaces facing
    the same way (2), or hidden behind a map surface from the submap's cameras (6)."""
    state = np.asarray(state)
    return (state == 2) | (state == 6)


def largest_area(state: np.ndarray, areas: np.ndarray, code: int) -> np.ndarray:
    """(H,) the area of each pose's largest submap plane whose verification ``state`` (H, S) is ``code`` (0 where
    none is); ``areas`` (S,)."""
    return np.where(np.asarray(state) == code, np.asarray(areas)[None, :], 0.0).max(axis=1, initial=0.0)


#: Codes of the ``forgiven`` argument of :func:`explains_enough` (0: none): a plane whose conflicts with the map are
#: forgiven at every pose, and one forgiven only at a pose matching ``far_conflict_min_planes`` planes or more.
FORGIVEN = 1
FORGIVEN_WELL_MATCHED = 2


def facet_mask(normals: np.ndarray, centroids: np.ndarray, areas: np.ndarray, distances: np.ndarray,
               max_area_m2: float) -> np.ndarray:
    """(S,) bool: the planes under ``max_area_m2`` that are facets of a curved surface seen from outside (a plant
    pot, a chair's back, a bin): each touches another plane of the set (``distances`` (S, S), the smallest distance
    between their verification samples, at most :data:`FACET_TOUCH_M`) whose normal is :data:`FACET_MIN_ANGLE_DEG`
    to :data:`FACET_MAX_ANGLE_DEG` away, the two bending away from each other (``(c_k - c_j) . (n_k - n_j) > 0``,
    as around a convex object; inside a bevelled room corner they bend towards each other). Extraction cuts a curved
    surface into facets whose orientation follows where it was seen from, so a map seen from elsewhere holds other
    facets of it, a few degrees and centimetres off."""
    n = np.asarray(normals, dtype=np.float64)
    c = np.asarray(centroids, dtype=np.float64)
    S = len(n)
    if S < 2 or max_area_m2 <= 0:
        return np.zeros(S, dtype=bool)
    cos = n @ n.T
    bend = np.einsum("jki,jki->jk", c[None, :, :] - c[:, None, :], n[None, :, :] - n[:, None, :])
    pair = ((cos >= math.cos(math.radians(FACET_MAX_ANGLE_DEG))) & (cos <= math.cos(math.radians(FACET_MIN_ANGLE_DEG)))
            & (bend > 0) & (np.asarray(distances) <= FACET_TOUCH_M))
    np.fill_diagonal(pair, False)
    return (np.asarray(areas) < max_area_m2) & pair.any(axis=1)


def duplicate_stacks(normals: np.ndarray, centroids: np.ndarray) -> np.ndarray:
    """(S,) float: the number of planes in the stack of duplicates each plane belongs to (1 for a plane alone). Two
    planes are duplicates when their centroids lie within :data:`DUPLICATE_MAX_DISTANCE_M` and their normals within
    :data:`DUPLICATE_MAX_ANGLE_DEG`; a stack is a chain of duplicates. A stereo camera's small face 4-5 m away, fitted
    in every frame of a window with its normal off by several degrees and its samples scattered by centimetres, is
    not associated across the frames by the submap's fusion (its samples fail the offset test), and comes out as up
    to a dozen planes at the same place. Kinect and ToF class noise leaves none on the suite's submaps."""
    n = np.asarray(normals, dtype=np.float64)
    c = np.asarray(centroids, dtype=np.float64)
    S = len(n)
    if S < 2:
        return np.ones(S)
    link = ((np.linalg.norm(c[:, None, :] - c[None, :, :], axis=2) <= DUPLICATE_MAX_DISTANCE_M)
            & (n @ n.T >= math.cos(math.radians(DUPLICATE_MAX_ANGLE_DEG))))
    np.fill_diagonal(link, True)
    label = np.arange(S)
    while True:  # each plane takes the lowest label among its duplicates until none changes: the chains' components
        new = np.where(link, label[None, :], S).min(axis=1)
        if np.array_equal(new, label):
            return np.bincount(label, minlength=S)[label].astype(np.float64)
        label = new


def explains_enough(explained, unknown, state, params: MatchingParams, n_matched=None, areas=None, match=None,
                    forgiven=None):
    """Whether each pose explains enough of the submap to be accepted (bool, shape of ``explained``).

    It explains ``min_explained_fraction``; or, with ``min_explained_known_fraction`` > 0, it explains at least that
    and its unexplained planes land only where the map knows nothing (no plane in conflict with a map surface or
    hidden behind one: :func:`in_conflict` nowhere; with ``areas`` (S,), the submap planes' areas, and
    ``known_conflict_min_area_m2`` > 0, no such plane of at least that area: a facet of curved clutter a few
    centimetres off a map surface does not decide it) and make up the rest (``explained + unknown >=
    min_explained_fraction``): a place the mapping run saw in part is not held against the true pose, while its
    rivals get the same credit (optimistic rivals) and the density margin still decides. With ``n_matched`` (the
    matched planes, shape of ``explained``) and ``well_matched_planes`` > 0, a pose matching that many planes or more
    also explains enough at ``well_matched_explained_fraction`` (for noisy sensors, see
    :func:`reloc.matching.params.scaled_to_sensor`). With ``forgiven`` (S,) (0, or :data:`FORGIVEN` (True) for the
    facets of curved clutter of :func:`facet_mask` and a noisy sensor's sparse planes laid over larger ones,
    :func:`reloc.matching.selection.sparse_overlays`, or :data:`FORGIVEN_WELL_MATCHED` for a noisy sensor's far
    planes, forgiven only at poses matching ``far_conflict_min_planes`` or more; the callers pass None when no rule
    marks a plane), ``match`` (the map plane per submap plane, shape of ``state``) and ``areas``, such a plane in
    conflict with the map is left out of the submap, as a plane too small to count is: the fractions are taken of the
    rest, and it does not spoil "the rest unknown to the map". (Rejection reasons and traces report the
    verification's fractions, over the whole submap.)
    """
    explained = np.asarray(explained, dtype=np.float64)
    conflict = None if state is None else in_conflict(state)
    left_out = None
    if forgiven is not None and match is not None and conflict is not None and areas is not None and np.any(forgiven):
        # The verification's weights (square roots of the areas) over the planes that count: those of at least
        # min_counted_area_m2, and smaller ones that matched.
        a = np.asarray(areas, dtype=np.float64)
        w = np.sqrt(a)
        counts = (a >= params.min_counted_area_m2) | (np.asarray(match) >= 0)
        codes = np.asarray(forgiven).astype(np.int8)
        left_out = codes == FORGIVEN
        if params.far_conflict_min_planes > 0 and n_matched is not None:
            # A noisy sensor's far planes: forgiven at the poses that match enough planes without them.
            well = np.asarray(n_matched)[..., None] >= params.far_conflict_min_planes
            left_out = left_out | ((codes == FORGIVEN_WELL_MATCHED) & well)
        left_out = conflict & left_out
        total = np.sum(np.where(counts, w, 0.0), axis=-1)
        rest = total - np.sum(np.where(left_out, w, 0.0), axis=-1)
        scale = np.where(rest > 0, total / np.where(rest > 0, rest, 1.0), 1.0)
        explained = explained * scale
        unknown = None if unknown is None else np.asarray(unknown) * scale
    ok = explained >= params.min_explained_fraction
    if params.well_matched_planes > 0 and n_matched is not None:
        ok |= (np.asarray(n_matched) >= params.well_matched_planes) & (
            explained >= params.well_matched_explained_fraction)
    if params.min_explained_known_fraction > 0 and unknown is not None and state is not None:
        bad = conflict if left_out is None else conflict & ~left_out
        if params.known_conflict_min_area_m2 > 0 and areas is not None:
            bad = bad & (np.asarray(areas) >= params.known_conflict_min_area_m2)
        clean = ~np.any(bad, axis=-1)
        ok |= (clean & (explained >= params.min_explained_known_fraction)
               & (explained + np.asarray(unknown) >= params.min_explained_fraction))
    return ok


def frequency_weights(
    R: np.ndarray, t: np.ndarray, match: np.ndarray, overlap: np.ndarray, quality: np.ndarray, params: MatchingParams,
    state: np.ndarray | None = None, areas: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Eq. 12-13: the weight ``w_a`` of each verified hypothesis, and the mode (group of nearby poses) of each.

    ``R`` (H, 3, 3), ``t`` (H, 3), ``match`` (H, S) map plane per submap plane (-1 none), ``overlap`` (H, S),
    ``quality`` (H,) the order in which hypotheses lead the grouping into modes (best first). With ``state`` (H, S)
    (see :class:`reloc.matching.relocalizer.Verification`), a plane that conflicts with the map under a hypothesis
    (state 2: a map surface facing the same way is there, but the plane does not line up with it; state 6: a map
    surface hides it from the submap's cameras) counts against it with the weight it would have had if matched:
    evidence against a pose, not merely missing evidence. With ``areas`` (S,), a plane's weight also grows with its
    area up to ``evidence_area_m2`` (a 0.2 m^2 facet is weaker evidence than a wall, and is more often clutter).
    Returns ``(w (H,), group (H,) int32, leaders (G,) int32, plane_w (S,))``: the leader of a mode is its best
    hypothesis; ``plane_w[j]`` is the weight a match of submap plane j carries (``1 / f_j``, 1 if never matched;
    with ``areas`` both times ``min(1, area_j / evidence_area_m2)``).
    """
    H = R.shape[0]
    order = np.argsort(-quality, kind="stable").astype(np.int64)
    group = np.empty(H, np.int32)
    leaders = K.group_poses(np.ascontiguousarray(R), np.ascontiguousarray(t), order, params.distinct_translation_m,
                            params.distinct_rotation_rad, group)
    G = len(leaders)
    matched = match >= 0
    per_group = np.zeros((G, match.shape[1]), dtype=bool)
    np.logical_or.at(per_group, group, matched)
    freq = per_group.sum(axis=0)  # modes in which each submap plane is matched
    inv = np.where(freq > 0, 1.0 / np.maximum(freq, 1), 0.0)
    reliability = np.ones(match.shape[1]) if areas is None else np.minimum(1.0, areas / params.evidence_area_m2)
    inv = inv * reliability
    w = np.sum(np.where(matched, overlap, 0.0) * inv[None, :], axis=1)
    plane_w = np.where(freq > 0, inv, reliability)
    if state is not None:
        w = np.maximum(w - np.sum(np.where(in_conflict(state), plane_w[None, :], 0.0), axis=1), 0.0)
    return w, group, leaders, plane_w


def pose_density(R: np.ndarray, t: np.ndarray, weights: np.ndarray, params: MatchingParams) -> np.ndarray:
    """Eq. 14 at every candidate pose, normalized by the total weight: (H,) values in [0, 1]."""
    info = np.array(
        [1.0 / params.kde_sigma_translation_m**2] * 3 + [1.0 / params.kde_sigma_rotation_rad**2] * 3
    )
    dens = np.empty(R.shape[0])
    K.kde_density(np.ascontiguousarray(R), np.ascontiguousarray(t), np.ascontiguousarray(weights, dtype=np.float64),
                  info, dens)
    z = float(np.sum(weights))
    return dens / z if z > 0 else dens


def decide(
    R: np.ndarray,
    t: np.ndarray,
    match: np.ndarray,
    overlap: np.ndarray,
    n_matched: np.ndarray,
    explained: np.ndarray,
    params: MatchingParams,
    *,
    min_matched: int | None = None,
    state: np.ndarray | None = None,
    areas: np.ndarray | None = None,
    free_frac: np.ndarray | None = None,
    unknown: np.ndarray | None = None,
    blocked: np.ndarray | None = None,
    hidden_frac: np.ndarray | None = None,
    optimistic: bool = True,
    timings_ms: dict | None = None,
    modes: dict | None = None,
    forgiven: np.ndarray | None = None,
    stacks: np.ndarray | None = None,
) -> Decision:
    """Pick the best pose among verified hypotheses, or reject with a reason.

    Every hypothesis competes (it may be the truth); only those matching ``min_matched`` planes (default
    ``params.min_matched_planes``) and explaining enough of the submap (:func:`explains_enough`) may win.

    ``state`` (H, S) (see :class:`reloc.matching.relocalizer.Verification`): planes conflicting with the map count
    against a hypothesis (:func:`frequency_weights`). Which hypotheses compete was settled by verification (a pose
    that may be the truth, given what the map does not know, competes); only a pose that itself explains enough
    can win. ``unknown`` (H,): the weight of each pose's planes unknown to the map (see :func:`explains_enough`).
    ``free_frac`` (H, S): the fraction of each unmatched plane's samples in the map's known free space, which shrinks
    the credit an optimistic rival gets for that plane. ``blocked`` (H,): poses whose camera path walks through a
    wall of the map (see ``MatchingParams.path_test``); their modes are no rivals, though they may still win.
    ``hidden_frac`` (H, S): the share of each plane the map hides from the submap's cameras, which shrinks an
    optimistic rival's credit for it too (``hidden_rival_credit``; none left at ``occlusion_min_fraction``).
    Without ``shared_unknown_credit``, once the winner is known and explains ``shared_unknown_min_explained`` of the
    submap, a rival matching fewer planes than it earns no credit for the planes the winner leaves unknown too.

    ``timings_ms``: when given, the milliseconds of the frequency weights (``"weights"``, Eq. 12-13) and of the kernel
    density (``"density"``, Eq. 14) are added to it. ``modes``: when given, it receives the poses' modes, for
    explaining the decision: ``group`` (H,) each hypothesis's mode, ``score`` (G,) the density at each mode (the
    winner's is the decision's score) and ``rival`` (G,) the density each mode has as a rival (with the credit of
    ``optimistic_rivals``; the runner-up is the largest of the modes distinct from the winner). ``forgiven`` (S,):
    the submap's facets of curved clutter (:func:`facet_mask`), sparse overlays and far planes, coded as
    :func:`explains_enough` reads them, whose conflicts do not keep a pose from explaining enough to win; its
    density and the rivals' are not changed. ``stacks`` (S,): the size of each plane's stack of duplicates
    (:func:`duplicate_stacks`, ``duplicate_credit_once``); an optimistic rival's credit for a plane is divided by it,
    so that one surface fitted several times is credited once. Matches and conflicts still count plane by plane.
    """
    H = R.shape[0]
    if H == 0:
        return Decision(False, "no hypothesis passed verification", -1, 0.0, 0.0, 0)
    quality = match_quality(n_matched, explained)
    t0 = time.perf_counter()
    w, group, leaders, plane_w = frequency_weights(R, t, match, overlap, quality, params, state, areas)
    t1 = time.perf_counter()
    n_modes = len(leaders)
    # Triplets of the same mode are not independent evidence: each mode counts once (its mean weight), however many
    # triplets gave it (otherwise a pose reachable through more map triplets, e.g. via a floor shared with the next
    # room, would win). The density (Eq. 14) is evaluated at the modes' leaders: O(G^2) for G modes, not O(H^2).
    size = np.bincount(group, minlength=n_modes)
    mode_w = np.bincount(group, weights=w, minlength=n_modes) / np.maximum(size, 1)
    density = pose_density(R[leaders], t[leaders], mode_w, params)
    t2 = time.perf_counter()
    need = params.min_matched_planes if min_matched is None else min_matched
    eligible = (n_matched >= need) & explains_enough(explained, unknown, state, params, n_matched, areas, match,
                                                     forgiven)
    best = g_best = -1
    if eligible.any():
        mode_ok = np.bincount(group, weights=eligible.astype(float), minlength=n_modes) > 0
        # Best: the eligible mode of highest density; its best eligible hypothesis carries the pose.
        g_best = int(np.flatnonzero(mode_ok)[np.argmax(density[mode_ok])])
        members = np.flatnonzero((group == g_best) & eligible)
        best = int(members[np.argmax(quality[members])])
    t3 = time.perf_counter()
    rival = density
    credited = optimistic and params.optimistic_rivals and state is not None
    if credited:
        # A rival is judged by what it might explain with a complete map: its planes that land where the map knows
        # nothing count as if matched (with the frequency weight such a match would carry), less so the more of
        # the plane's place the map saw empty (``free_frac``; at ``max_free_fraction`` it would contradict the map).
        credit = np.where(state == 1, plane_w[None, :], 0.0)
        if free_frac is not None and params.max_free_fraction > 0:
            credit = credit * np.clip(1.0 - free_frac / params.max_free_fraction, 0.0, 1.0)
        if hidden_frac is not None and params.hidden_rival_credit and params.occlusion_min_fraction > 0:
            # A plane the twin pose puts partly behind a wall of the map (a door jamb inside it) is partly a plane
            # no camera could have seen there: at occlusion_min_fraction it counts against the pose (state 6).
            credit = credit * np.clip(1.0 - hidden_frac / params.occlusion_min_fraction, 0.0, 1.0)
        if (best >= 0 and not params.shared_unknown_credit
                and explained[best] >= params.shared_unknown_min_explained):
            # A plane the winner leaves unknown to the map too cannot tell the two apart: a rival that matches fewer
            # planes earns nothing for it. A rival matching as many (a twin room) keeps the credit, and so do the
            # rivals of a winner that leaves more of its submap unknown: there the credit is the margin that keeps
            # a wrong winner, with the truth no hypothesis or contradicted by a map that saw its room less, from
            # standing.
            shared = (np.asarray(state)[best] == 1)[None, :] & (np.asarray(n_matched) < n_matched[best])[:, None]
            credit = np.where(shared, 0.0, credit)
        if stacks is not None:
            # One surface fitted several times is one plane the rival might match (a stereo face 4.7 m away, fitted
            # as 12 planes at one place, credited as 12 planes turned a corridor view's true pose away).
            credit = credit / np.asarray(stacks, dtype=np.float64)[None, :]
        # The credit adds to the rival's evidence before it is clipped at zero: planes in conflict with the map
        # still count against it (a pose that contradicts the map more than it matches gains nothing from
        # planes the map does not know).
        gain = np.sum(np.where(match >= 0, overlap, 0.0) * plane_w[None, :], axis=1)
        against = np.sum(np.where(in_conflict(state), plane_w[None, :], 0.0), axis=1)
        w_opt = np.maximum(gain - against + params.rival_unknown_weight * np.sum(credit, axis=1), 0.0)
        mode_opt = np.bincount(group, weights=w_opt, minlength=n_modes) / np.maximum(size, 1)
        # On the scale of the score (normalized by the poses' actual total weight); when conflicts leave no pose
        # any weight, the score is 0 whatever the rivals hold, and they are normalized by their own total.
        z = float(mode_w.sum())
        rival = pose_density(R[leaders], t[leaders], mode_opt, params)
        if z > 0:
            rival = rival * (float(mode_opt.sum()) / z)
    if blocked is not None and np.any(blocked):
        # A pose whose camera path walks through a wall of the map is no rival (it may still win: a map wall
        # drawn across a doorway must not turn the true pose away).
        rival = np.where(np.asarray(blocked)[leaders], 0.0, rival)
    if modes is not None:
        modes.update(group=group, score=density, rival=rival)
    if timings_ms is not None:
        t4 = time.perf_counter()
        timings_ms["weights"] = timings_ms.get("weights", 0.0) + (t1 - t0) * 1e3
        timings_ms["density"] = timings_ms.get("density", 0.0) + (t2 - t1 + t4 - t3) * 1e3
    if best < 0:
        a = int(np.argmax(quality))
        return Decision(
            False,
            f"no pose explains enough: best {int(n_matched[a])} planes, {explained[a]:.2f} of the submap (needs "
            f"{need} and {params.min_explained_fraction}"
            + (f", or {params.well_matched_explained_fraction} with {params.well_matched_planes} planes"
               if params.well_matched_planes > 0 else "")
            + (f", or {params.min_explained_known_fraction} with the rest unknown to the map)"
               if params.min_explained_known_fraction > 0 else ")"),
            -1, 0.0, 0.0, n_modes,
        )
    score = float(density[g_best])
    other = distinct_from(R[leaders], t[leaders], int(np.flatnonzero(leaders == leaders[g_best])[0]), params)
    other &= np.arange(n_modes) != g_best
    runner = float(rival[other].max()) if other.any() else 0.0
    if score <= 0.0:
        return Decision(False, "no pose keeps any evidence: its planes in conflict with the map outweigh its matches",
                        best, score, runner, n_modes)
    if score < params.min_score:
        return Decision(False, f"score {score:.3f} below {params.min_score}", best, score, runner, n_modes)
    if runner > 0 and score < params.min_ambiguity_ratio * runner:
        return Decision(
            False,
            f"ambiguous: {n_modes} poses, best score {score:.3f} not {params.min_ambiguity_ratio}x the runner-up "
            f"{runner:.3f}"
            + (" (rivals judged with credit for their planes where the map knows nothing)" if credited else ""),
            best, score, runner, n_modes,
        )
    return Decision(True, "", best, score, runner, n_modes)


def match_quality(n_matched: np.ndarray, explained: np.ndarray) -> np.ndarray:
    """How well each hypothesis matched, to rank hypotheses and modes: its matched planes plus its explained
    fraction."""
    return np.asarray(n_matched).astype(np.float64) + explained


def ratio(score: float, runner_up: float) -> float:
    """``score / runner_up`` (inf without a runner-up)."""
    return math.inf if runner_up <= 0 else score / runner_up
