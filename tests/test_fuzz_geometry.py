"""Fuzzing geometry: degenerate point sets into plane fitting and point-cloud extraction, and degenerate plane sets
into map building and relocalization.

Points: a single point, identical points, collinear points, two points, exact planes (also 1e6 m from the origin
and with a spread of 1e-9 m), random clouds, coordinates of 1e30, NaN and inf rows. Property: ``fit_plane`` returns
a finite unit normal oriented toward the sensor, through exactly coplanar points when they are (any plane through a
line or a point is such a plane); ``extract_planes_from_points`` returns finite planes with unit normals. Or
``ValueError``.

Plane sets (``RELOC_TARGET``): 0 to 9 planes, parallel, antiparallel, identical, duplicated, with a single sample or
none, tiny or huge (1e6 m) offsets, any gravity, mixed into a real view of the map's room or not; fed to
``build_map`` and to ``Relocalizer.locate`` in a furnished room. Property: the map is finite with unit normals; a
relocalization is a rigid pose whose matched planes' normals span 3-D (planes that are all parallel or span only a
plane never fix a pose), and a real view still relocalizes at its true pose when it is relocalized. Or
``ValueError``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from reloc.evaluation.synthetic import furnished_room, look_at, planes_from_points, scene_planes, view_planes
from reloc.extraction import ExtractionParams, fit_plane, noise_sigma
from reloc.extraction.fit import MAX_COORDINATE_M
from reloc.extraction.pipeline import extract_planes_from_points
from reloc.mapping import MapBuilder, MappingParams
from reloc.matching import Relocalizer
from reloc.transforms import check_transform, pose_error
from test_fuzz_common import Target, fuzz_settings, outcome

EXTRACT = ExtractionParams(min_plane_points=20, min_points_per_voxel=5, min_plane_area_m2=0.0)
unit = st.tuples(*[st.floats(-1, 1)] * 3).filter(lambda v: np.linalg.norm(v) > 0.2).map(
    lambda v: np.array(v) / np.linalg.norm(v))


def _plane_grid(normal, offset, n_side, spacing, center_shift=0.0):
    n = np.asarray(normal)
    a = np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(n, a)
    s = (np.arange(n_side) - (n_side - 1) / 2) * spacing
    A, B = np.meshgrid(s, s)
    c = -offset * n + center_shift * a
    return c + A.reshape(-1, 1) * a + B.reshape(-1, 1) * b


@st.composite
def point_sets(draw) -> tuple[np.ndarray, bool, np.ndarray]:
    """(points (N, 3), exactly coplanar, sensor origin (3,))."""
    kind = draw(st.integers(0, 8))
    origin = np.zeros(3)
    base = np.array(draw(st.tuples(*[st.floats(-5, 5)] * 3))) + np.array([0, 0, 6.0])
    if kind == 0:  # one point, or identical points
        return np.tile(base, (draw(st.integers(1, 50)), 1)), True, origin
    if kind == 1:  # collinear
        t = np.linspace(-1, 1, draw(st.integers(2, 60)))[:, None]
        return base + t * draw(unit), True, origin
    if kind == 2:  # an exact plane, possibly far away or tiny
        scale = draw(st.sampled_from([1.0, 1.0, 1e-9, 1e-4, 1e3]))
        shift = draw(st.sampled_from([0.0, 0.0, 1e6, -1e6, 1e4]))
        n = draw(unit)
        pts = _plane_grid(n, draw(st.floats(0.5, 5)), draw(st.integers(2, 25)), 0.05 * scale, shift)
        if shift and draw(st.booleans()):
            # Far from the sensor too: thousands of metres sideways at a few metres of depth, outside any camera's
            # field of view. The ray-form fit is ill-conditioned there (a known limit: the plane is finite and
            # oriented, not exact), so only planes seen from a sensor near them are held to exactness.
            return pts, False, origin
        if shift:  # a sensor 3 m in front of the far plane (the frame of a map 1e6 m from its origin)
            origin = pts.mean(axis=0) + 3.0 * n * np.sign(n @ -pts.mean(axis=0) or 1.0)
        return pts, True, origin
    if kind == 3:  # random cloud
        rng = np.random.default_rng(draw(st.integers(0, 999)))
        return base + rng.normal(0, draw(st.floats(1e-6, 3)), (draw(st.integers(0, 400)), 3)), False, origin
    if kind == 4:  # huge coordinates
        v = draw(st.sampled_from([1e30, -1e30, 1e300, 3.4e38, 1e6]))
        pts = np.tile(base, (draw(st.integers(3, 30)), 1))
        pts[:, draw(st.integers(0, 2))] += v * np.linspace(0, 1, len(pts))
        return pts, False, origin
    if kind == 5:  # a plane with NaN / inf rows
        pts = _plane_grid(draw(unit), 2.0, 20, 0.05)
        rng = np.random.default_rng(draw(st.integers(0, 999)))
        bad = rng.random(len(pts)) < draw(st.floats(0, 1))
        pts[bad, rng.integers(0, 3)] = draw(st.sampled_from([np.nan, np.inf, -np.inf]))
        return pts, True, origin
    if kind == 6:  # two parallel planes (a slab), or two crossing planes
        n = draw(unit)
        p1 = _plane_grid(n, 2.0, 15, 0.05)
        p2 = _plane_grid(n if draw(st.booleans()) else draw(unit), 2.0 + draw(st.floats(0, 0.05)), 15, 0.05)
        return np.vstack([p1, p2]), False, origin
    if kind == 7:  # points at and behind the sensor
        pts = np.tile(np.zeros(3), (draw(st.integers(3, 40)), 1))
        pts[:, 2] = -np.abs(np.linspace(0, draw(st.floats(0, 5)), len(pts)))
        return pts, False, origin
    # empty or fewer than three
    return np.zeros((draw(st.integers(0, 2)), 3)) + base, True, origin


def check_points(pts: np.ndarray, coplanar: bool, origin: np.ndarray) -> None:
    finite = pts[np.isfinite(pts).all(axis=1)]
    try:
        n, d, cov = fit_plane(pts, sensor_origin=origin)
    except ValueError:
        assert len(finite) < 3 or np.abs(finite).max() > MAX_COORDINATE_M, "fit_plane refused usable points"
    else:
        assert np.isfinite(n).all() and np.isfinite(d) and np.isfinite(cov).all(), (n, d)
        assert abs(np.linalg.norm(n) - 1) < 1e-9
        assert n @ origin + d >= -1e-9 * max(1.0, float(np.abs(origin).max())), "the normal points toward the sensor"
        rel = finite - origin
        in_view = np.all(rel[:, 2] > np.tan(np.radians(10)) * np.linalg.norm(rel[:, :2], axis=1))
        if coplanar and in_view:
            # Points within 80 degrees of the viewing axis (a ray form at grazing rays is ill-conditioned: beyond,
            # the plane is only held to be finite and oriented).
            # Through the points within 10% of the sensor's noise at their depth (the fit weighs by that noise: a
            # patch of a few micrometres is placed within it, not exactly), 10 um, and 1e-8 of their distance.
            far = float(np.abs(finite).max())
            depth = float(np.abs(finite[:, 2] - origin[2]).max())
            tolerance = 1e-5 + 1e-8 * far + 0.1 * float(noise_sigma(depth))
            assert np.abs(finite @ n + d).max() <= tolerance, np.abs(finite @ n + d).max()
    planes = extract_planes_from_points(pts, EXTRACT, sensor_origin=origin).planes
    assert np.isfinite(planes.normals).all() and np.isfinite(planes.offsets).all()
    assert np.isfinite(planes.sample_points).all() and np.isfinite(planes.covariances).all()
    if len(planes):
        assert np.allclose(np.linalg.norm(planes.normals, axis=1), 1.0, atol=1e-6)


def run_points(case) -> str:
    return outcome(lambda: check_points(*case), names=None, timeout_s=60)


TARGET = Target("geometry", "points into plane fitting and extraction", point_sets(), run_points)


@fuzz_settings(100)
@given(point_sets())
def test_fuzzed_point_sets_fit_valid_planes(case):
    run_points(case)


# --- plane sets into map building and relocalization ----------------------------------------------------------

ROOM = furnished_room("office")
_MAP = None


def relocalizer() -> Relocalizer:
    global _MAP
    if _MAP is None:
        _MAP = Relocalizer(scene_planes(ROOM))
    return _MAP


@st.composite
def plane_sets(draw) -> tuple:
    """(plane set in a camera frame, T_map_cam of the real view it contains or None)."""
    k = draw(st.integers(0, 9))
    pieces, normals, offsets = [], [], []
    first = draw(unit)
    for _ in range(k):
        kind = draw(st.integers(0, 4))
        if kind == 0 and normals:  # a copy of an earlier plane
            j = draw(st.integers(0, len(normals) - 1))
            n, d = normals[j], offsets[j]
        elif kind == 1:  # parallel or antiparallel to the first
            n, d = first * draw(st.sampled_from([1.0, -1.0])), draw(st.floats(0.1, 5))
        else:
            n, d = draw(unit), draw(st.one_of(st.floats(0.0, 6), st.sampled_from([1e-9, 1e6, -1e6])))
        size = draw(st.sampled_from([1, 1, 2, 10, 50]))
        pts = _plane_grid(n, d, int(np.sqrt(size)) or 1, draw(st.sampled_from([0.1, 1e-6, 1.0])))
        pieces.append(pts)
        normals.append(np.asarray(n, float))
        offsets.append(float(d))
    gravity = draw(st.one_of(st.none(), unit, st.just(np.array([0.0, 1.0, 0.0]))))
    junk = planes_from_points(pieces, np.array(normals).reshape(-1, 3), np.array(offsets), spacing=0.1, frame="cam",
                              gravity=gravity)
    T = None
    if draw(st.integers(0, 5)) == 0 and len(junk):  # a corrupted field: must be refused, not matched
        field = draw(st.sampled_from(["normals", "offsets", "centroids", "areas", "radii", "sample_points"]))
        arr = getattr(junk, field).copy()
        if arr.size:
            arr.reshape(-1)[draw(st.integers(0, arr.size - 1))] = draw(st.sampled_from([np.nan, np.inf, -1.0, 3.0]))
            junk = replace(junk, **{field: arr})
        return junk, None
    if draw(st.booleans()):  # mixed into a real view of the room
        T = look_at((draw(st.floats(1.0, 5.0)), draw(st.floats(1.0, 4.0)), 1.2), (3.0, 2.5, 0.8))
        view = view_planes(ROOM, T)
        junk = _concat(view, junk.transformed(np.eye(4), "cam")) if len(junk) else view
    return junk, T


def _concat(a, b):
    fields = ("normals", "offsets", "centroids", "counts", "radii", "areas", "covariances", "sums", "scatters")
    out = {f: np.concatenate([getattr(a, f), getattr(b, f)]) for f in fields}
    pts = np.concatenate([a.sample_points, b.sample_points])
    ptr = np.concatenate([a.sample_ptr, b.sample_ptr[1:] + a.sample_ptr[-1]])
    return replace(a, **out, sample_points=pts, sample_ptr=ptr, labels=None)


def check_planes_case(planes, T_map_cam) -> None:
    try:
        planes.check_geometry("planes")
    except ValueError:  # corrupted on purpose: relocalization must refuse it, naming it
        try:
            relocalizer().locate(planes)
        except ValueError as exc:
            assert "submap" in str(exc)
            raise
        raise AssertionError("a plane set with non-finite or invalid geometry was matched")
    # Map building: the plane set as three keyframes from nearby poses.
    builder = MapBuilder(MappingParams(min_observations=1, free_space_voxel_m=0.0))
    for x in (0.0, 0.3, 0.6):
        T = np.eye(4)
        T[0, 3] = x
        builder.add(planes, T)
    pm = builder.finish()
    p = pm.planes
    assert np.isfinite(p.normals).all() and np.isfinite(p.offsets).all() and np.isfinite(p.sample_points).all()
    if len(p):
        assert np.allclose(np.linalg.norm(p.normals, axis=1), 1.0, atol=1e-6)
    assert np.isfinite(pm.gravity).all()
    # Relocalization in the furnished room.
    result = relocalizer().locate(planes)
    assert result.status in ("relocalized", "rejected")
    if result.relocalized:
        T = check_transform(result.T_map_cam, "T_map_cam")
        n_matched = planes.normals[result.matched[:, 0]]
        assert np.linalg.svd(n_matched, compute_uv=False)[-1] > 0.1, "a pose from planes that do not span 3-D"
        if T_map_cam is not None:
            dt, dr_deg = pose_error(T, T_map_cam)
            assert dt < 0.05 and dr_deg < 1.0, (dt, dr_deg)
    else:
        assert result.T_map_cam is None and result.reason


def run_planes(case) -> str:
    return outcome(lambda: check_planes_case(*case), names=None, timeout_s=60)


RELOC_TARGET = Target("relocalizer", "plane sets into map building and matching", plane_sets(), run_planes)


@fuzz_settings(60)
@given(plane_sets())
def test_fuzzed_plane_sets_build_maps_and_relocalize_or_reject(case):
    run_planes(case)


def test_a_real_view_relocalizes_at_its_pose():
    T = look_at((1.0, 1.0, 1.2), (3.0, 2.5, 0.8))
    result = relocalizer().locate(view_planes(ROOM, T))
    assert result.relocalized, result.reason
    assert run_planes((view_planes(ROOM, T), T)) == "ok"


# Regressions found by the fuzzer (each a silent NaN plane before its fix).


def test_overflowing_coordinates_are_a_value_error():
    pts = np.tile([4.5, 2.2, 6.0], (10, 1))
    pts[:, 2] += 1.6e299 * np.linspace(0, 1, 10)  # a NaN plane (and a wrong orientation) before
    assert outcome(lambda: fit_plane(pts), names="points") == "error"
    assert outcome(lambda: extract_planes_from_points(pts, EXTRACT), names="points") == "error"


def test_subnormal_coordinates_give_a_finite_plane():
    t = np.linspace(0, 1, 8)[:, None]
    pts = np.array([-0.9, 1e-158, 6.4]) + t * np.array([0.97, -1e-159, -0.4])  # NaN plane before
    n, d, _ = fit_plane(pts)
    assert np.isfinite(n).all() and np.abs(pts @ n + d).max() < 1e-9


def test_non_finite_or_invalid_plane_sets_are_refused_by_the_relocalizer():
    # Matched before (an inf offset or a NaN sample relocalized; a NaN map normal silently lost a plane).
    T = look_at((1.0, 1.0, 1.2), (3.0, 2.5, 0.8))
    view = view_planes(ROOM, T)
    for field, value in [("offsets", np.inf), ("sample_points", np.nan), ("normals", 3.0), ("areas", -1.0)]:
        arr = getattr(view, field).copy()
        arr.reshape(-1)[1] = value
        assert outcome(lambda: relocalizer().locate(replace(view, **{field: arr})), names="submap") == "error"
    room = scene_planes(ROOM)
    normals = room.normals.copy()
    normals[0] = np.nan
    assert outcome(lambda: Relocalizer(replace(room, normals=normals)), names="plane_map") == "error"


def test_a_cloud_whose_planes_all_drop_out_in_refinement_gives_no_plane():
    # A plane 10 km sideways of the sensor: every merged plane is dropped in the last refinement pass, and
    # renumbering the points indexed an empty table (IndexError) before.
    pts = _plane_grid(np.array([0.9920792231604355, 0.0, 0.12561375312196912]), 2.6, 24, 0.05, 1e4)
    planes = extract_planes_from_points(pts, EXTRACT).planes
    assert np.isfinite(planes.normals).all() and np.isfinite(planes.offsets).all()
