"""Outcomes of relocalization queries and the paper-style tables (Table 1, Table 3).

Counting follows the paper, made explicit:

- a positive query (taken in the mapped scene) answered with a pose within ``0.25 m`` and ``5 deg`` of the truth
  is TP; answered with a wrong pose it is FP; rejected it is FN;
- a negative query (taken in another scene) rejected is TN; accepted it is FP;
- a positive query whose view is indistinguishable from another place of the scene (identical rooms, a symmetric
  room: see :mod:`reloc.evaluation.ambiguity`) has no unique answer: rejected it counts as TN (correct refusal),
  accepted it counts as FP (a guess), whatever the pose. Such queries are left out of the recall.

Precision ``P = TP / (TP + FP)``, recall ``R = TP / (TP + FN)``.

A positive, unambiguous query is *identifiable* when the map confirms its true pose by the checks a winning pose
must pass (:meth:`reloc.matching.Relocalizer.confirm`: matched planes, explained fraction, support along the
weakest direction, after the least-squares refinement, within the TP thresholds of the truth). A query that is not
identifiable cannot be answered right by any search under the same acceptance rules: its submap does not pin the
pose down (a corridor view with nothing across the corridor) or the map does not hold what it sees. ``R_id``, the
recall over the identifiable queries, is what the search and the decision among poses lose; ``R`` also counts what
the planes cannot tell. Both are over the positives ``R`` counts, TP and FN: a positive answered with a wrong pose
(FP) is in neither (it was in ``R_id``'s, which could then fall below ``R``, and the identifiable count could
exceed TP + FN).

An identifiable query is *unique* when, moreover, no symmetric twin of its true pose (``S @ T`` for each symmetry
``S`` of the scene: the next meeting room, the corridor turned end for end; see
:func:`reloc.evaluation.ambiguity.scene_symmetries`) is confirmed too (:func:`twin_confirmed`). A view that is not
ambiguous to the renderer (a few per cent of its pixels differ from its twin's) may still be one whose planes pass
the winner's tests at the twin as well: then only the decision's scores can tell the truth from the twin, and
where they are close it rejects the view as ambiguous. ``R_un``, the recall over the unique queries, leaves those
views out too (an answered one among them counts in ``R`` and ``R_id``, not in ``R_un``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Outcome", "classify", "covariance_check", "identifiable", "twin_confirmed", "Summary", "summarize",
           "format_table", "CHI2_6_95", "TP_MAX_TRANSLATION_M", "TP_MAX_ROTATION_DEG"]

TP_MAX_TRANSLATION_M = 0.25
TP_MAX_ROTATION_DEG = 5.0


@dataclass(frozen=True)
class Outcome:
    """One query's result: ``label`` is TP, FP, FN or TN; errors are NaN unless a pose was returned for a positive."""

    scene: str
    query: str
    positive: bool
    ambiguous: bool
    status: str
    reason: str
    label: str
    translation_error_m: float = math.nan
    rotation_error_deg: float = math.nan
    total_ms: float = math.nan
    timings_ms: dict = field(default_factory=dict)
    counts: dict = field(default_factory=dict)
    identifiable: bool | None = None  # None: a negative or ambiguous query, or not checked
    identifiable_reason: str = ""  # why the true pose is not confirmed (empty when it is)
    twin_confirmed: bool | None = None  # a symmetric twin of the true pose is confirmed too (None: not checked)
    # A positive's answer judged by its own covariance (NaN without one): delta^T cov^-1 delta of its error, a
    # chi-square of 6 dof when the covariance describes the errors, and the covariance's translation sigma (m).
    pose_nees: float = math.nan
    pose_sigma_m: float = math.nan

    def to_dict(self) -> dict:
        def num(v):
            return None if v is None or (isinstance(v, float) and not math.isfinite(v)) else round(float(v), 6)

        return {
            "scene": self.scene, "query": self.query, "positive": self.positive, "ambiguous": self.ambiguous,
            "status": self.status, "reason": self.reason, "label": self.label,
            "translation_error_m": num(self.translation_error_m), "rotation_error_deg": num(self.rotation_error_deg),
            "total_ms": num(self.total_ms), "timings_ms": {k: num(v) for k, v in self.timings_ms.items()},
            "counts": dict(self.counts), "identifiable": self.identifiable,
            "identifiable_reason": self.identifiable_reason, "twin_confirmed": self.twin_confirmed,
            "pose_nees": num(self.pose_nees), "pose_sigma_m": num(self.pose_sigma_m),
        }


# 95 % of a chi-square of 6 degrees of freedom: a pose error outside this normalized squared distance lies outside its
# covariance's 95 % ellipsoid.
CHI2_6_95 = 12.59


def covariance_check(T_est, T_true, covariance) -> tuple[float, float]:
    """``(delta^T cov^-1 delta, sigma_t)`` of an answer ``T_est`` against ``T_true`` (both 4x4 ``T_map_cam``), with
    ``delta = log(T_true T_est^-1)`` (the left perturbation in the map frame that its ``covariance`` (6, 6) is over)
    and ``sigma_t`` the square root of the covariance's translation trace; NaNs without a covariance."""
    if covariance is None:
        return math.nan, math.nan
    from reloc.transforms import invert, log_se3

    cov = np.asarray(covariance, dtype=np.float64)
    delta = log_se3(np.asarray(T_true, dtype=np.float64) @ invert(np.asarray(T_est, dtype=np.float64)))
    return float(delta @ np.linalg.solve(cov, delta)), math.sqrt(max(float(np.trace(cov[:3, :3])), 0.0))


def classify(positive: bool, ambiguous: bool, relocalized: bool, errors: tuple[float, float] | None) -> str:
    """TP / FP / FN / TN of one query (see the module docstring)."""
    if not positive or ambiguous:
        return "FP" if relocalized else "TN"
    if not relocalized:
        return "FN"
    t_err, r_err = errors
    return "TP" if t_err <= TP_MAX_TRANSLATION_M and r_err <= TP_MAX_ROTATION_DEG else "FP"


def identifiable(relocalizer, submap, T_true) -> tuple[bool, str]:
    """Whether the true pose ``T_true`` (4, 4, map frame) of a positive query is identifiable: ``relocalizer`` (a
    :class:`reloc.matching.Relocalizer`) confirms it (:meth:`~reloc.matching.Relocalizer.confirm`) and its refined
    pose is within the TP thresholds of the truth. Returns ``(identifiable, reason)``, the reason empty when it is."""
    from reloc.transforms import pose_error

    check = relocalizer.confirm(submap, T_true)
    if not check.relocalized:
        return False, check.reason
    t_err, r_err = pose_error(check.T_map_cam, T_true)
    if t_err > TP_MAX_TRANSLATION_M or r_err > TP_MAX_ROTATION_DEG:
        return False, f"refined true pose {t_err:.2f} m, {r_err:.1f} deg off"
    return True, ""


def twin_confirmed(relocalizer, submap, T_true, symmetries) -> bool:
    """Whether ``relocalizer`` confirms a symmetric twin ``S @ T_true`` of the true pose (4, 4) for some ``S`` of
    ``symmetries`` (4x4 world-to-world transforms, :func:`reloc.evaluation.ambiguity.scene_symmetries`) as it would
    the truth (:func:`identifiable`: its refined pose within the TP thresholds of the twin)."""
    from reloc.transforms import pose_error

    for S in symmetries:
        T_twin = np.asarray(S, dtype=np.float64) @ np.asarray(T_true, dtype=np.float64)
        check = relocalizer.confirm(submap, T_twin)
        if not check.relocalized:
            continue
        t_err, r_err = pose_error(check.T_map_cam, T_twin)
        if t_err <= TP_MAX_TRANSLATION_M and r_err <= TP_MAX_ROTATION_DEG:
            return True
    return False


@dataclass(frozen=True)
class Summary:
    name: str
    TP: int
    TN: int
    FP: int
    FN: int
    ambiguous: int
    precision: float
    recall: float
    median_translation_error_m: float
    median_rotation_error_deg: float
    mean_ms: float
    median_ms: float
    p95_ms: float
    stage_mean_ms: dict
    identifiable: int = 0  # positive, unambiguous queries (TP or FN) whose true pose the map confirms
    identified: int = 0  # of those, the TPs
    recall_identifiable: float = math.nan  # identified / identifiable
    unique: int = 0  # identifiable queries with no symmetric twin of the true pose confirmed as well
    identified_unique: int = 0  # of those, the TPs
    recall_unique: float = math.nan  # identified_unique / unique
    covariance_checked: int = 0  # TPs with a covariance
    within_95: float = math.nan  # the share of them whose error lies inside its covariance's 95 % ellipsoid
    median_sigma_m: float = math.nan  # their covariances' translation sigma, median

    def to_dict(self) -> dict:
        out = {}
        for k, v in self.__dict__.items():
            if isinstance(v, float):
                out[k] = None if not math.isfinite(v) else round(v, 6)
            else:
                out[k] = v
        return out


def summarize(name: str, outcomes: list[Outcome]) -> Summary:
    """Counts, precision, recall (also over the identifiable queries), median pose errors of the TPs and times
    over ``outcomes``."""
    labels = [o.label for o in outcomes]
    tp, tn, fp, fn = (labels.count(x) for x in ("TP", "TN", "FP", "FN"))
    counted = [o for o in outcomes if o.label in ("TP", "FN")]  # the positives of R = TP / (TP + FN)
    identifiable = sum(o.identifiable is True for o in counted)
    identified = sum(o.identifiable is True and o.label == "TP" for o in counted)
    unique = sum(o.identifiable is True and o.twin_confirmed is False for o in counted)
    identified_unique = sum(o.identifiable is True and o.twin_confirmed is False and o.label == "TP" for o in counted)
    errs = np.array([(o.translation_error_m, o.rotation_error_deg) for o in outcomes if o.label == "TP"]).reshape(-1, 2)
    times = np.array([o.total_ms for o in outcomes if math.isfinite(o.total_ms)])
    checked = [o for o in outcomes if o.label == "TP" and math.isfinite(o.pose_nees)]
    stages: dict[str, list[float]] = {}
    for o in outcomes:
        for k, v in o.timings_ms.items():
            stages.setdefault(k, []).append(v)
    return Summary(
        name=name, TP=tp, TN=tn, FP=fp, FN=fn, ambiguous=sum(o.ambiguous for o in outcomes),
        precision=tp / (tp + fp) if tp + fp else math.nan,
        recall=tp / (tp + fn) if tp + fn else math.nan,
        median_translation_error_m=float(np.median(errs[:, 0])) if len(errs) else math.nan,
        median_rotation_error_deg=float(np.median(errs[:, 1])) if len(errs) else math.nan,
        mean_ms=float(times.mean()) if len(times) else math.nan,
        median_ms=float(np.median(times)) if len(times) else math.nan,
        p95_ms=float(np.percentile(times, 95)) if len(times) else math.nan,
        stage_mean_ms={k: float(np.mean(v)) for k, v in stages.items()},
        identifiable=identifiable, identified=identified,
        recall_identifiable=identified / identifiable if identifiable else math.nan,
        unique=unique, identified_unique=identified_unique,
        recall_unique=identified_unique / unique if unique else math.nan,
        covariance_checked=len(checked),
        within_95=float(np.mean([o.pose_nees < CHI2_6_95 for o in checked])) if checked else math.nan,
        median_sigma_m=float(np.median([o.pose_sigma_m for o in checked])) if checked else math.nan,
    )


def _fmt(v: float, scale: float = 1.0, digits: int = 2) -> str:
    return "-" if not math.isfinite(v) else f"{v * scale:.{digits}f}"


def format_table(rows: list[Summary], first_column: str = "scene") -> str:
    """A plain-text table: name, TP TN FP FN, ambiguous, P %, R %, identifiable queries and the recall over them,
    unique queries and the recall over them, median errors (cm, deg), mean/median ms."""
    head = (f"{first_column:<16} {'TP':>4} {'TN':>4} {'FP':>4} {'FN':>4} {'amb':>4} {'P[%]':>7} {'R[%]':>7} "
            f"{'ident':>5} {'R_id[%]':>7} {'uniq':>5} {'R_un[%]':>7} {'t_err[cm]':>9} {'r_err[deg]':>10} "
            f"{'mean[ms]':>9} {'med[ms]':>8}")
    lines = [head, "-" * len(head)]
    for s in rows:
        lines.append(
            f"{s.name:<16} {s.TP:>4} {s.TN:>4} {s.FP:>4} {s.FN:>4} {s.ambiguous:>4} {_fmt(s.precision, 100):>7} "
            f"{_fmt(s.recall, 100):>7} {s.identifiable:>5} {_fmt(s.recall_identifiable, 100):>7} "
            f"{s.unique:>5} {_fmt(s.recall_unique, 100):>7} {_fmt(s.median_translation_error_m, 100):>9} "
            f"{_fmt(s.median_rotation_error_deg, 1, 3):>10} {_fmt(s.mean_ms, 1, 1):>9} {_fmt(s.median_ms, 1, 1):>8}"
        )
    return "\n".join(lines)
