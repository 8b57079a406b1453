"""Why a query came out as it did: the poses the decision weighed, and what each submap plane was under them.

For the developer of a rule and for the operator of a map: ``reloc eval --prepared DIR --explain QUERY`` prints
:func:`explain_query` for a query of a saved suite, with its ground truth.
"""

from __future__ import annotations

import math

import numpy as np

from reloc.evaluation.metrics import identifiable, twin_confirmed
from reloc.matching.relocalizer import PLANE_STATES, Relocalizer
from reloc.matching.scoring import in_conflict, match_quality
from reloc.planeset import PlaneSet
from reloc.transforms import pose_error, transform_from_rotation_translation

__all__ = ["explain_query", "explain_result"]


def _modes(hyps, tight: bool, params, max_modes: int) -> list[int]:
    """Rows of ``hyps`` to show: every mode of a decision over refined poses (one row each), else the best raw
    hypothesis of each distinct pose, best first."""
    order = np.argsort(-match_quality(hyps.n_matched, hyps.explained), kind="stable")
    if tight:
        return [int(i) for i in order[:max_modes]]
    rows: list[int] = []
    max_deg = math.degrees(params.distinct_rotation_rad)
    for i in order:
        apart = [pose_error(_pose(hyps, i), _pose(hyps, k)) for k in rows]
        if all(dt > params.distinct_translation_m or deg > max_deg for dt, deg in apart):
            rows.append(int(i))
            if len(rows) == max_modes:
                break
    return rows


def _pose(hyps, i: int) -> np.ndarray:
    return transform_from_rotation_translation(hyps.R[i], hyps.t[i])


def _pose_columns(label: str, hyps, i: int, T_true: np.ndarray | None) -> str:
    """The first columns of a pose's row in the table of poses weighed: its label, its distance to the truth (blank
    without ``T_true``), matched planes, explained and unknown fractions and planes in conflict."""
    to_truth = "" if T_true is None else "%8.2f %6.1f" % pose_error(_pose(hyps, i), T_true)
    conflicts = int(np.count_nonzero(in_conflict(hyps.state[i])))
    return (f"  {label:>2s}  {to_truth:>15s}  {int(hyps.n_matched[i]):6d}  {hyps.explained[i]:9.2f}  "
            f"{hyps.unknown[i]:7.2f}  {conflicts:9d}")


def _outside_footprint(relocalizer: Relocalizer, trace: dict, shown) -> list[str]:
    """One line naming, per pose shown, the planes unknown to the map that it puts partly outside the map's footprint
    and the share (``footprint_rival_credit``: that share, over ``occlusion_min_fraction``, of their credit as a
    rival is taken off); no line when there are none or the decision cuts no credit that way."""
    fp = relocalizer.credit_footprint
    if fp is None:
        return []
    vs_ptr, vs_pts = trace["samples"]
    notes = []
    for name, h, i in shown:
        share = fp.outside_share(vs_ptr, vs_pts, h.R[i:i + 1], h.t[i:i + 1])[0]
        js = [j for j in range(len(share)) if h.state[i, j] == 1 and share[j] > 0]
        if js:
            notes.append(f"pose {name}: " + ", ".join(f"{j} ({share[j]:.2f})" for j in js))
    if not notes:
        return []
    return [f"planes unknown to the map that a pose puts outside the map's footprint (share of their samples; a "
            f"rival's credit for each shrinks by share / {relocalizer.params.occlusion_min_fraction:g}): "
            + "; ".join(notes)]


def explain_query(relocalizer: Relocalizer, submap: PlaneSet, T_true: np.ndarray | None = None, *,
                  max_modes: int = 8, symmetries=()) -> str:
    """A text account of ``relocalizer.locate(submap)``: the result (with its pose error when ``T_true``, the
    ground truth ``T_map_cam``, is given), the decision over the raw hypotheses and, when made, the one over refined
    poses; the poses weighed (per mode: distance to the truth, matched planes, explained and unknown fractions of
    the submap, planes in conflict, whether it has a least-squares pose, its score in the decision and its score as
    a rival, which the winner's must exceed ``min_ambiguity_ratio`` times, 0 for a pose whose camera path walks
    through a wall of the map); the stronger pose that turned an early winner away, when one did (row ``S``); what
    each submap plane was under the decision's best pose, the pose nearest the truth, the strongest other pose and
    that stronger pose (its state, and the map plane it matched, -1 for none); and whether the true pose is
    identifiable (:func:`reloc.evaluation.metrics.identifiable`: the map confirms it as ``locate`` would accept
    it) and, with the scene's ``symmetries``, whether a symmetric twin of it is confirmed too
    (:func:`reloc.evaluation.metrics.twin_confirmed`)."""
    trace: dict = {}
    res = relocalizer.locate(submap, trace=trace)
    return explain_result(relocalizer, submap, res, trace, T_true, max_modes=max_modes, symmetries=symmetries)


def explain_result(relocalizer: Relocalizer, submap: PlaneSet, res, trace: dict, T_true: np.ndarray | None = None,
                   *, max_modes: int = 8, identified: tuple[bool, str] | None = None, symmetries=()) -> str:
    """:func:`explain_query` of a result already there: ``res`` and ``trace`` from ``relocalizer.locate(submap,
    trace=trace)``; ``identified``, when the caller has it, is :func:`identifiable`'s answer for ``T_true``."""
    out = [f"result: {res.status}" + (f" ({res.reason})" if res.reason else "")]
    if res.relocalized and T_true is not None:
        e = pose_error(res.T_map_cam, T_true)
        out.append(f"  pose error {100 * e[0]:.1f} cm, {e[1]:.2f} deg")
    if res.relocalized and "direction_support" in trace:
        # The last test the answer passed, with its margin: how close it came to being turned away.
        support, against = trace["direction_support"]
        less = (f", less {against:.2f} m^2 the map hides from its cameras or has in conflict" if against is not None
                else "")
        line = (f"  along its weakest direction {support:.2f} m^2 of matched planes{less} "
                f"(needs {relocalizer.params.min_direction_support_m2})")
        if trace.get("weak_slide") is not None:
            # Short of that support, it stood as the only peak along the direction (``weak_slide_range_m``).
            shift, n = trace["weak_slide"]
            line += (f"; short of it, the only peak along it: the best copy slid {shift:+.2f} m matches {n} planes "
                     f"against {res.counts.get('matched_surfaces', 0)}")
        out.append(line)
    c = res.counts
    out.append(f"  {c.get('planes_used', 0)} of {c.get('submap_planes', 0)} submap planes used, "
               f"{c.get('candidates', 0)} candidate triplets, {c.get('verified', 0)} transforms verified, "
               f"{c.get('passed', 0)} passed")
    if "raw" not in trace:
        return "\n".join(out)
    raw_d = trace["raw_decision"]
    out.append(f"decision over {len(trace['raw'])} verified hypotheses: "
               + ("accepted" if raw_d.accepted else f"rejected ({raw_d.reason})")
               + f", {raw_d.n_modes} poses, score {raw_d.score:.3f}, runner-up {raw_d.runner_up_score:.3f}")
    hyps, tight, decision, modes = trace["judged"], trace["tight"], trace["decision"], trace["modes"]
    if tight:
        out.append(f"decision over refined poses ({len(hyps)} modes): "
                   + ("accepted" if decision.accepted else f"rejected ({decision.reason})")
                   + f", score {decision.score:.3f}, runner-up {decision.runner_up_score:.3f}")
    if not len(hyps):
        return "\n".join(out)
    rows = _modes(hyps, tight, relocalizer.params, max_modes)
    out.append("poses weighed" + (" (one per mode, as decided)" if tight else " (the best raw hypothesis per pose)")
               + ":")
    out.append("   #  to truth [m, deg]  planes  explained  unknown  conflicts  least squares   score  as rival")
    nearest, blocked = None, hyps.blocked()
    if T_true is not None:
        nearest = min(range(len(hyps)), key=lambda i: pose_error(_pose(hyps, i), T_true)[0])
    for i in rows:
        refined = ("yes" if hyps.is_refined(i) else "no") if tight else "-"
        role = "winner" if (decision.accepted and i == decision.best) else ("best" if i == decision.best else "")
        role += " (nearest the truth)" if i == nearest else ""
        if tight and blocked is not None and blocked[i]:
            why = ("a large plane in conflict with or hidden behind the map, too little explained" if hyps.is_vetoed(i)
                   else "its cameras walk through a wall")
            role = f"{role} ({why}: no rival)".lstrip()
        scores = "%6.3f  %8.3f" % (modes["score"][modes["group"][i]], modes["rival"][modes["group"][i]]) if modes \
            else "%6s  %8s" % ("-", "-")
        out.append(f"{_pose_columns(str(i), hyps, i, T_true)}  {refined:>13s}  {scores}  {role}".rstrip())
    # The planes under the decision's best pose, the pose nearest the truth and the strongest other pose, and the
    # stronger pose that turned the winner away, if one did.
    other = next((i for i in rows if i not in (decision.best, nearest)), None)
    shown = [(str(i), hyps, i) for i in dict.fromkeys([decision.best, nearest, other]) if i is not None and i >= 0]
    if "stronger" in trace:
        poses, a = trace["stronger"]
        out.append("the stronger pose found among the planes fed last (it turned the winner away):")
        out.append(_pose_columns("S", poses, a, T_true))
        shown.append(("S", poses, a))
    used = trace["used"]
    states = ", ".join(f"{k} {w}" for k, w in enumerate(PLANE_STATES))
    out.append("submap planes under poses " + ", ".join(name for name, _, _ in shown)
               + f" (state and map plane, -1 for none; states: {states}):")
    out.append(("   j  area [m^2]  normal (map, pose %s)  " % shown[0][0]
                + "".join(f"  pose {name:<9s}" for name, _, _ in shown)).rstrip())
    first, b = shown[0][1:]
    for j in range(len(used)):
        n = first.R[b] @ used.normals[j]
        cells = "".join(f"  {PLANE_STATES[h.state[i, j]]:<9s}{int(h.match[i, j]):>5d}" for _, h, i in shown)
        out.append(f"  {j:2d}  {used.areas[j]:10.2f}  ({n[0]:5.2f} {n[1]:5.2f} {n[2]:5.2f})   {cells}")
    out.extend(_outside_footprint(relocalizer, trace, shown) if tight else [])
    if T_true is not None:
        ident, why = identified if identified is not None else identifiable(relocalizer, submap, T_true)
        out.append("the true pose: " + ("identifiable (the map confirms it as locate would accept it)" if ident
                                        else f"not identifiable ({why})"))
        if ident and len(symmetries):
            twin = twin_confirmed(relocalizer, submap, T_true, symmetries)
            out.append("  " + ("a symmetric twin of it is confirmed too (only the decision's scores can tell the two "
                               "apart)" if twin else "no symmetric twin of it is confirmed: unique"))
    return "\n".join(out)
