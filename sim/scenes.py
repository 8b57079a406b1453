"""Indoor scenes made of planar polygons with known plane parameters, plus non-planar clutter.

World frame: metres, z up, floor at ``z = 0``. Every planar surface is a plane ``n . p + d = 0`` with a stable id
(1, 2, ... in construction order, so the same name and seed always give the same ids) made of one or more convex
polygons: a wall with a door opening is one plane of several rectangles, and the floor of all rooms of a scene is
one plane. Normals point into the free space the surface faces (walls into their room, box faces outward).

Clutter (vertical cylinders, spheres) is rendered but carries no plane id: it is where outliers come from.

For trajectories, a scene also keeps its walkable layout: room rectangles, doorway passages and furniture
footprints (``free_space.py`` uses them).

``make_scene(name, seed)`` builds one of: living_room, office, apartment, corridor, meeting_rooms, symmetric_room,
random, building. The hand-made scenes ignore ``seed`` (their world frame never changes); ``random`` and
``building`` are generated from it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Scene", "SceneBuilder", "make_scene", "SCENE_NAMES"]

SCENE_NAMES = ("living_room", "office", "apartment", "corridor", "meeting_rooms", "symmetric_room", "random", "building")

DOOR_W = 0.9
DOOR_H = 2.05
WALL_T = 0.12  # thickness of interior walls (the gap between two rooms' wall faces)


@dataclass(frozen=True)
class Scene:
    """A static indoor scene.

    Planes (world frame, one row per plane):
    - ``plane_ids`` (P,) int32, ids from 1; ``normals`` (P, 3) unit; ``offsets`` (P,); ``plane_kinds`` names
      (floor, ceiling, wall, jamb, door, furniture, tilted).
    Polygons (convex, planar): vertices of polygon ``q`` are ``poly_vertices[poly_ptr[q]:poly_ptr[q + 1]]``
    (world, float64), on plane index ``poly_plane[q]``.
    Clutter: ``cylinders`` (C, 5) ``[x, y, z_bottom, z_top, radius]`` (vertical), ``spheres`` (S, 4)
    ``[x, y, z, radius]``.
    Layout: ``rooms`` (R, 5) ``[x0, y0, x1, y1, height]``, ``passages`` (D, 5) ``[x0, y0, x1, y1, axis]``
    (doorways, axis 0 = walk along x), ``obstacles`` (O, 4) footprints ``[x0, y0, x1, y1]``.
    """

    name: str
    seed: int
    plane_ids: np.ndarray
    normals: np.ndarray
    offsets: np.ndarray
    plane_kinds: tuple[str, ...]
    poly_vertices: np.ndarray
    poly_ptr: np.ndarray
    poly_plane: np.ndarray
    cylinders: np.ndarray
    spheres: np.ndarray
    rooms: np.ndarray
    passages: np.ndarray
    obstacles: np.ndarray
    # Derived per-polygon arrays the renderer takes as they are.
    poly_normals: np.ndarray = field(init=False, repr=False)
    poly_offsets: np.ndarray = field(init=False, repr=False)
    poly_labels: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "poly_normals", np.ascontiguousarray(self.normals[self.poly_plane]))
        object.__setattr__(self, "poly_offsets", np.ascontiguousarray(self.offsets[self.poly_plane]))
        object.__setattr__(self, "poly_labels", np.ascontiguousarray(self.plane_ids[self.poly_plane], np.int32))

    @property
    def n_planes(self) -> int:
        return int(self.plane_ids.shape[0])

    @property
    def n_polygons(self) -> int:
        return int(self.poly_ptr.shape[0] - 1)

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) min and max corner of all polygons."""
        return np.stack([self.poly_vertices.min(axis=0), self.poly_vertices.max(axis=0)])

    def index_of(self, plane_id: int) -> int:
        """Row of plane ``plane_id``; raises ValueError when the scene has no such plane."""
        idx = np.flatnonzero(self.plane_ids == plane_id)
        if idx.size != 1:
            raise ValueError(f"plane_id: scene {self.name!r} has no plane {plane_id} (ids 1..{self.n_planes})")
        return int(idx[0])

    def polygons_of(self, index: int) -> list[np.ndarray]:
        """The polygons (each (k, 3) world) of plane row ``index``."""
        qs = np.flatnonzero(self.poly_plane == index)
        return [self.poly_vertices[self.poly_ptr[q] : self.poly_ptr[q + 1]] for q in qs]

    def plane_areas(self) -> np.ndarray:
        """(P,) total polygon area of each plane, m^2."""
        areas = np.zeros(self.n_planes)
        for q in range(self.n_polygons):
            v = self.poly_vertices[self.poly_ptr[q] : self.poly_ptr[q + 1]]
            cross = np.cross(v[1:-1] - v[0], v[2:] - v[0]).sum(axis=0)
            areas[self.poly_plane[q]] += 0.5 * np.linalg.norm(cross)
        return areas


class SceneBuilder:
    """Accumulates planes, polygons, clutter and layout; ``build()`` freezes them into a :class:`Scene`.

    Shapes are added by small methods (rooms with door openings, doorways between rooms, closed doors in niches,
    boxes, tables, sofas, wedges, tilted panels, cylinders, spheres). Plane ids follow the order of the calls.
    """

    def __init__(self, name: str, seed: int = 0) -> None:
        self.name = name
        self.seed = int(seed)
        self._normals: list[np.ndarray] = []
        self._offsets: list[float] = []
        self._kinds: list[str] = []
        self._polys: list[tuple[int, np.ndarray]] = []
        self._shared: dict[tuple, int] = {}
        self.cylinders: list[tuple[float, ...]] = []
        self.spheres: list[tuple[float, ...]] = []
        self.rooms: list[tuple[float, ...]] = []
        self.passages: list[tuple[float, ...]] = []
        self.obstacles: list[tuple[float, ...]] = []

    # -- planes -----------------------------------------------------------------------------------------------
    def plane(self, kind: str, normal, point, polys=()) -> int:
        """New plane through ``point`` with ``normal``; returns its row index. ``polys`` are added to it."""
        n = np.asarray(normal, dtype=np.float64)
        n = n / np.linalg.norm(n)
        self._normals.append(n)
        self._offsets.append(float(-n @ np.asarray(point, dtype=np.float64)))
        self._kinds.append(kind)
        idx = len(self._normals) - 1
        for p in polys:
            self.polygon(idx, p)
        return idx

    def shared_plane(self, kind: str, normal, point) -> int:
        """The one plane of this kind, normal and offset (the floor, a ceiling height), made on first use."""
        n = np.asarray(normal, dtype=np.float64)
        n = n / np.linalg.norm(n)
        key = (kind, *np.round(n, 9), round(float(-n @ np.asarray(point, dtype=np.float64)), 9))
        if key not in self._shared:
            self._shared[key] = self.plane(kind, n, point)
        return self._shared[key]

    def polygon(self, plane_index: int, vertices) -> None:
        """Add a convex planar polygon (k, 3) to plane row ``plane_index`` (checked: on the plane and convex)."""
        v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
        n, d = self._normals[plane_index], self._offsets[plane_index]
        off = np.abs(v @ n + d).max()
        if v.shape[0] < 3 or off > 1e-9:
            raise ValueError(f"polygon: expected >= 3 vertices on plane {plane_index}, got {v.shape[0]} off by {off:.3g}")
        e = np.roll(v, -1, axis=0) - v
        turns = np.cross(e, np.roll(e, -1, axis=0)) @ n
        if not (np.all(turns >= -1e-12) or np.all(turns <= 1e-12)):
            raise ValueError(f"polygon: expected a convex polygon, got turns {turns.tolist()}")
        self._polys.append((plane_index, v))

    # -- rooms and doors ----------------------------------------------------------------------------------------
    def room(self, x0, y0, x1, y1, height, openings=None, floor=True, ceiling=True, walls=True) -> list[int]:
        """A box room seen from inside: floor (shared), ceiling (shared per height) and four walls.

        ``openings`` maps a side ('x-', 'x+', 'y-', 'y+') to a list of ``(centre, width, height)`` door openings
        along that wall (centre as the x or y coordinate). Returns the wall plane rows (x-, x+, y-, y+).
        """
        openings = openings or {}
        self.rooms.append((x0, y0, x1, y1, height))
        if floor:
            f = self.shared_plane("floor", (0, 0, 1), (0, 0, 0))
            self.polygon(f, [(x0, y0, 0), (x1, y0, 0), (x1, y1, 0), (x0, y1, 0)])
        if ceiling:
            c = self.shared_plane("ceiling", (0, 0, -1), (0, 0, height))
            self.polygon(c, [(x0, y0, height), (x0, y1, height), (x1, y1, height), (x1, y0, height)])
        rows = []
        if walls:
            for side in ("x-", "x+", "y-", "y+"):
                rows.append(self.wall(side, x0, y0, x1, y1, height, openings.get(side, ())))
        return rows

    def wall(self, side, x0, y0, x1, y1, height, openings=()) -> int:
        """One wall face of the room rectangle, facing into it, with rectangular door openings cut out."""
        if side in ("x-", "x+"):
            pos, s0, s1 = (x0 if side == "x-" else x1), y0, y1
            normal = (1, 0, 0) if side == "x-" else (-1, 0, 0)
            to3 = lambda s, z: (pos, s, z)  # noqa: E731
        elif side in ("y-", "y+"):
            pos, s0, s1 = (y0 if side == "y-" else y1), x0, x1
            normal = (0, 1, 0) if side == "y-" else (0, -1, 0)
            to3 = lambda s, z: (s, pos, z)  # noqa: E731
        else:
            raise ValueError(f"side: expected one of 'x-', 'x+', 'y-', 'y+', got {side!r}")
        idx = self.plane("wall", normal, to3(s0, 0.0))
        rects = []
        cursor = s0
        for c, w, dh in sorted(openings):
            a, b = c - w / 2, c + w / 2
            if a < s0 - 1e-9 or b > s1 + 1e-9 or a < cursor - 1e-9:
                raise ValueError(f"openings: door at {c} (width {w}) does not fit the wall {s0}..{s1}")
            if a > cursor + 1e-9:
                rects.append((cursor, a, 0.0, height))
            if dh < height - 1e-9:
                rects.append((a, b, dh, height))
            cursor = b
        if s1 > cursor + 1e-9:
            rects.append((cursor, s1, 0.0, height))
        for sa, sb, za, zb in rects:
            self.polygon(idx, [to3(sa, za), to3(sb, za), to3(sb, zb), to3(sa, zb)])
        return idx

    def doorway(self, axis, p0, p1, centre, width=DOOR_W, height=DOOR_H, panel=False, passage=True) -> None:
        """The frame of a door opening through a wall between ``p0`` and ``p1`` (coordinates along ``axis``).

        Adds the two jambs, the lintel underside and the floor of the threshold. With ``panel`` the opening is a
        closed door in a niche: a door leaf at ``p1`` facing back toward ``p0``. With ``passage`` the opening is
        walkable (recorded for trajectories).
        """
        a, b = centre - width / 2, centre + width / 2
        f = self.shared_plane("floor", (0, 0, 1), (0, 0, 0))
        if axis == "x":
            self.plane("jamb", (0, 1, 0), (p0, a, 0), [[(p0, a, 0), (p1, a, 0), (p1, a, height), (p0, a, height)]])
            self.plane("jamb", (0, -1, 0), (p0, b, 0), [[(p0, b, 0), (p0, b, height), (p1, b, height), (p1, b, 0)]])
            self.plane("jamb", (0, 0, -1), (p0, a, height),
                       [[(p0, a, height), (p1, a, height), (p1, b, height), (p0, b, height)]])
            self.polygon(f, [(p0, a, 0), (p1, a, 0), (p1, b, 0), (p0, b, 0)])
            if panel:
                sign = -1.0 if p1 > p0 else 1.0
                self.plane("door", (sign, 0, 0), (p1, a, 0), [[(p1, a, 0), (p1, b, 0), (p1, b, height), (p1, a, height)]])
            if passage:
                lo, hi = min(p0, p1), max(p0, p1)
                self.passages.append((lo - 0.6, a, hi + 0.6, b, 0))
        elif axis == "y":
            self.plane("jamb", (1, 0, 0), (a, p0, 0), [[(a, p0, 0), (a, p1, 0), (a, p1, height), (a, p0, height)]])
            self.plane("jamb", (-1, 0, 0), (b, p0, 0), [[(b, p0, 0), (b, p0, height), (b, p1, height), (b, p1, 0)]])
            self.plane("jamb", (0, 0, -1), (a, p0, height),
                       [[(a, p0, height), (b, p0, height), (b, p1, height), (a, p1, height)]])
            self.polygon(f, [(a, p0, 0), (b, p0, 0), (b, p1, 0), (a, p1, 0)])
            if panel:
                sign = -1.0 if p1 > p0 else 1.0
                self.plane("door", (0, sign, 0), (a, p1, 0), [[(a, p1, 0), (b, p1, 0), (b, p1, height), (a, p1, height)]])
            if passage:
                lo, hi = min(p0, p1), max(p0, p1)
                self.passages.append((a, lo - 0.6, b, hi + 0.6, 1))
        else:
            raise ValueError(f"axis: expected 'x' or 'y', got {axis!r}")

    def closed_door(self, side, room, centre, width=DOOR_W, height=DOOR_H, recess=0.06) -> None:
        """A closed door in a niche of the room's wall ``side`` (the wall must have the matching opening)."""
        x0, y0, x1, y1 = room
        if side == "x-":
            self.doorway("x", x0, x0 - recess, centre, width, height, panel=True, passage=False)
        elif side == "x+":
            self.doorway("x", x1, x1 + recess, centre, width, height, panel=True, passage=False)
        elif side == "y-":
            self.doorway("y", y0, y0 - recess, centre, width, height, panel=True, passage=False)
        elif side == "y+":
            self.doorway("y", y1, y1 + recess, centre, width, height, panel=True, passage=False)
        else:
            raise ValueError(f"side: expected one of 'x-', 'x+', 'y-', 'y+', got {side!r}")

    # -- furniture ------------------------------------------------------------------------------------------------
    def box(self, cx, cy, sx, sy, z0, z1, yaw=0.0, kind="furniture", obstacle=True, bottom=None) -> list[int]:
        """An oriented box (centre ``cx, cy``, size ``sx x sy``, from ``z0`` to ``z1``, turned by ``yaw`` rad).

        Faces: top, four sides and (when it floats, ``z0 > 0``) the bottom, each its own plane, normals outward.
        """
        c, s = math.cos(yaw), math.sin(yaw)
        local = [(-sx / 2, -sy / 2), (sx / 2, -sy / 2), (sx / 2, sy / 2), (-sx / 2, sy / 2)]
        xy = [(cx + c * a - s * b, cy + s * a + c * b) for a, b in local]  # counter-clockwise
        rows = [self.plane(kind, (0, 0, 1), (cx, cy, z1), [[(x, y, z1) for x, y in xy]])]
        for i in range(4):
            (ax, ay), (bx, by) = xy[i], xy[(i + 1) % 4]
            n = (by - ay, -(bx - ax), 0.0)
            rows.append(self.plane(kind, n, (ax, ay, z0), [[(ax, ay, z0), (bx, by, z0), (bx, by, z1), (ax, ay, z1)]]))
        if bottom if bottom is not None else z0 > 1e-9:
            rows.append(self.plane(kind, (0, 0, -1), (cx, cy, z0), [[(x, y, z0) for x, y in reversed(xy)]]))
        if obstacle:
            xs, ys = [p[0] for p in xy], [p[1] for p in xy]
            self.obstacles.append((min(xs), min(ys), max(xs), max(ys)))
        return rows

    def table(self, cx, cy, sx, sy, height=0.74, top=0.04, yaw=0.0, leg_r=0.025) -> list[int]:
        """A table: a top slab (box faces, bottom included) on four cylinder legs (clutter)."""
        rows = self.box(cx, cy, sx, sy, height - top, height, yaw=yaw)
        c, s = math.cos(yaw), math.sin(yaw)
        for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
            la, lb = a * (sx / 2 - 0.06), b * (sy / 2 - 0.06)
            self.cylinder(cx + c * la - s * lb, cy + s * la + c * lb, 0.0, height - top, leg_r, obstacle=False)
        return rows

    def sofa(self, cx, cy, length=2.0, depth=0.9, yaw=0.0) -> None:
        """A sofa facing +y of its own frame (turned by ``yaw``): seat, back and two arms, all boxes."""
        c, s = math.cos(yaw), math.sin(yaw)

        def place(a, b):
            return cx + c * a - s * b, cy + s * a + c * b

        arm = 0.18
        back = 0.2
        # Local frame: the back spans y in [-depth/2, -depth/2 + back], seat and arms the rest.
        x, y = place(0.0, back / 2)
        self.box(x, y, length - 2 * arm, depth - back, 0.0, 0.45, yaw=yaw, obstacle=False)
        x, y = place(0.0, -depth / 2 + back / 2)
        self.box(x, y, length, back, 0.0, 0.85, yaw=yaw, obstacle=False)
        for sgn in (-1, 1):
            x, y = place(sgn * (length / 2 - arm / 2), back / 2)
            self.box(x, y, arm, depth - back, 0.0, 0.62, yaw=yaw, obstacle=False)
        xs, ys = zip(*(place(a, b) for a in (-length / 2, length / 2) for b in (-depth / 2, depth / 2)))
        self.obstacles.append((min(xs), min(ys), max(xs), max(ys)))

    def wedge(self, cx, cy, length, width, rise, yaw=0.0) -> int:
        """A ramp rising by ``rise`` over ``length`` along its own +x (turned by ``yaw``); returns the slope's row."""
        c, s = math.cos(yaw), math.sin(yaw)

        def p(a, b, z):
            return (cx + c * a - s * b, cy + s * a + c * b, z)

        L, W = length / 2, width / 2
        slope = [p(-L, -W, 0), p(L, -W, rise), p(L, W, rise), p(-L, W, 0)]
        n = np.cross(np.subtract(slope[1], slope[0]), np.subtract(slope[3], slope[0]))
        row = self.plane("tilted", n, slope[0], [slope])
        self.plane("furniture", (c, s, 0), p(L, 0, 0), [[p(L, -W, 0), p(L, W, 0), p(L, W, rise), p(L, -W, rise)]])
        self.plane("furniture", (s, -c, 0), p(0, -W, 0), [[p(-L, -W, 0), p(L, -W, 0), p(L, -W, rise)]])
        self.plane("furniture", (-s, c, 0), p(0, W, 0), [[p(-L, W, 0), p(L, W, rise), p(L, W, 0)]])
        xs, ys = zip(*(p(a, b, 0)[:2] for a in (-L, L) for b in (-W, W)))
        self.obstacles.append((min(xs), min(ys), max(xs), max(ys)))
        return row

    def tilted_panel(self, cx, cy, z_bottom, width, height, yaw, tilt, kind="tilted") -> int:
        """A thin flat panel (a monitor, a leaning board): ``width x height``, its front facing ``yaw`` (rad, the
        horizontal direction it faces), leaning back by ``tilt`` rad from vertical, bottom edge centred at
        ``(cx, cy, z_bottom)``. One two-sided polygon."""
        f = np.array([math.cos(yaw), math.sin(yaw), 0.0])
        r = np.array([math.sin(yaw), -math.cos(yaw), 0.0])
        up = math.cos(tilt) * np.array([0.0, 0.0, 1.0]) - math.sin(tilt) * f
        b = np.array([cx, cy, z_bottom])
        verts = [b - r * width / 2, b + r * width / 2, b + r * width / 2 + up * height, b - r * width / 2 + up * height]
        n = math.cos(tilt) * f + math.sin(tilt) * np.array([0.0, 0.0, 1.0])
        return self.plane(kind, n, b, [verts])

    def cylinder(self, x, y, z0, z1, radius, obstacle=True) -> None:
        self.cylinders.append((x, y, z0, z1, radius))
        if obstacle:
            self.obstacles.append((x - radius, y - radius, x + radius, y + radius))

    def sphere(self, x, y, z, radius, obstacle=True) -> None:
        self.spheres.append((x, y, z, radius))
        if obstacle:
            self.obstacles.append((x - radius, y - radius, x + radius, y + radius))

    def plant(self, x, y) -> None:
        """A pot (cylinder) with foliage (sphere)."""
        self.cylinder(x, y, 0.0, 0.4, 0.17)
        self.sphere(x, y, 0.75, 0.35)

    def floor_lamp(self, x, y) -> None:
        self.cylinder(x, y, 0.0, 1.5, 0.02)
        self.sphere(x, y, 1.6, 0.18)

    # -- freeze -----------------------------------------------------------------------------------------------------
    def build(self) -> Scene:
        order = sorted(range(len(self._polys)), key=lambda q: self._polys[q][0])
        polys = [self._polys[q] for q in order]
        sizes = np.array([len(v) for _, v in polys], dtype=np.int64)
        ptr = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)

        def arr(rows, width):
            return np.asarray(rows, dtype=np.float64).reshape(-1, width)

        return Scene(
            name=self.name,
            seed=self.seed,
            plane_ids=np.arange(1, len(self._normals) + 1, dtype=np.int32),
            normals=np.asarray(self._normals, dtype=np.float64).reshape(-1, 3),
            offsets=np.asarray(self._offsets, dtype=np.float64),
            plane_kinds=tuple(self._kinds),
            poly_vertices=np.ascontiguousarray(np.concatenate([v for _, v in polys]) if polys else np.zeros((0, 3))),
            poly_ptr=ptr,
            poly_plane=np.array([p for p, _ in polys], dtype=np.int64),
            cylinders=arr(self.cylinders, 5),
            spheres=arr(self.spheres, 4),
            rooms=arr(self.rooms, 5),
            passages=arr(self.passages, 5),
            obstacles=arr(self.obstacles, 4),
        )


# -- the scenes ----------------------------------------------------------------------------------------------------


def _living_room(seed: int) -> Scene:
    """A 6 x 4.5 m living room with a doorway to a small hall; sofa, coffee table, shelf, TV unit, a ramp, clutter."""
    b = SceneBuilder("living_room", seed)
    h = 2.6
    b.room(0.0, 0.0, 6.0, 4.5, h, openings={"y-": [(1.2, DOOR_W, DOOR_H)]})
    hall = (0.3, -2.0 - WALL_T, 2.3, -WALL_T)
    b.room(*hall, h, openings={"y+": [(1.2, DOOR_W, DOOR_H)], "x+": [(hall[1] + 1.0, DOOR_W, DOOR_H)]})
    b.closed_door("x+", hall, hall[1] + 1.0)
    b.doorway("y", -WALL_T, 0.0, 1.2)
    b.sofa(3.2, 3.85, length=2.2, depth=0.9, yaw=math.pi)
    b.table(3.2, 2.6, 1.1, 0.6, height=0.42, top=0.05)
    b.box(0.25, 2.6, 0.4, 1.6, 0.0, 0.55)  # TV unit along the x- wall
    b.box(0.18, 2.6, 0.08, 1.1, 0.7, 1.35)  # TV standing on it
    b.box(5.55, 1.5, 0.38, 1.0, 0.0, 1.9)  # bookshelf along the x+ wall
    b.box(5.0, 3.9, 0.8, 0.8, 0.0, 0.45, yaw=0.4)  # armchair seat block
    b.wedge(4.3, 0.6, 1.0, 0.9, 0.22)  # a ramp: the tilted plane
    b.plant(0.5, 4.0)
    b.floor_lamp(5.6, 4.1)
    b.sphere(2.3, 1.4, 0.0 + 0.11, 0.11)  # a ball on the floor
    return b.build()


def _office(seed: int) -> Scene:
    """A 5 x 4 m office with a doorway to a corridor stub; two desks with tilted monitors, cabinets, shelf."""
    b = SceneBuilder("office", seed)
    h = 2.8
    b.room(0.0, 0.0, 5.0, 4.0, h, openings={"x-": [(3.2, DOOR_W, DOOR_H)]})
    corr = (-1.8 - WALL_T, 0.5, -WALL_T, 6.0)
    b.room(*corr, h, openings={"x+": [(3.2, DOOR_W, DOOR_H)], "y+": [(corr[0] + 0.9, DOOR_W, DOOR_H)]})
    b.doorway("x", -WALL_T, 0.0, 3.2)
    b.closed_door("y+", corr, corr[0] + 0.9)
    for dx in (1.5, 3.5):
        b.table(dx, 0.45, 1.4, 0.7, height=0.74)
        b.tilted_panel(dx, 0.35, 0.85, 0.55, 0.33, yaw=math.pi / 2, tilt=math.radians(15))
        b.box(dx + 0.45, 0.55, 0.4, 0.5, 0.0, 0.6)  # drawer cabinet under the desk
        b.cylinder(dx - 0.1, 1.3, 0.0, 0.48, 0.26)  # office chair, as clutter
    b.box(4.75, 2.8, 0.4, 1.0, 0.0, 2.0)  # tall shelf
    b.box(2.5, 3.7, 1.2, 0.5, 0.0, 1.1)  # sideboard
    b.cylinder(0.4, 1.3, 0.0, 0.35, 0.15)  # bin
    b.plant(0.45, 0.4)
    return b.build()


def _apartment(seed: int) -> Scene:
    """Five rooms round a hall: living room, kitchen, bedroom, bathroom, study; doorways between them."""
    b = SceneBuilder("apartment", seed)
    h = 2.6
    t = WALL_T
    # Hall runs along x from 0 to 10, y in [4, 5.6]; rooms south (y < 4) and north (y > 5.6).
    hall = (0.0, 4.0, 10.0, 5.6)
    living = (0.0, 0.0, 5.0, 4.0 - t)
    kitchen = (5.0 + t, 0.0, 10.0, 4.0 - t)
    bedroom = (0.0, 5.6 + t, 4.0, 9.5)
    bath = (4.0 + t, 5.6 + t, 6.5, 9.5)
    study = (6.5 + t, 5.6 + t, 10.0, 9.5)
    b.room(*hall, h, openings={
        "y-": [(2.5, DOOR_W, DOOR_H), (7.5, DOOR_W, DOOR_H)],
        "y+": [(2.0, DOOR_W, DOOR_H), (5.25, 0.8, DOOR_H), (8.2, DOOR_W, DOOR_H)],
        "x-": [(4.8, DOOR_W, DOOR_H)],
    })
    b.closed_door("x-", hall[:4], 4.8)  # the front door
    b.room(*living, h, openings={"y+": [(2.5, DOOR_W, DOOR_H)], "x+": [(2.0, 1.2, DOOR_H)]})
    b.room(*kitchen, h, openings={"y+": [(7.5, DOOR_W, DOOR_H)], "x-": [(2.0, 1.2, DOOR_H)]})
    b.room(*bedroom, h, openings={"y-": [(2.0, DOOR_W, DOOR_H)]})
    b.room(*bath, h, openings={"y-": [(5.25, 0.8, DOOR_H)]})
    b.room(*study, h, openings={"y-": [(8.2, DOOR_W, DOOR_H)]})
    b.doorway("y", 4.0 - t, 4.0, 2.5)
    b.doorway("y", 4.0 - t, 4.0, 7.5)
    b.doorway("y", 5.6, 5.6 + t, 2.0)
    b.doorway("y", 5.6, 5.6 + t, 5.25, width=0.8)
    b.doorway("y", 5.6, 5.6 + t, 8.2)
    b.doorway("x", 5.0, 5.0 + t, 2.0, width=1.2)
    # Living room.
    b.sofa(2.3, 0.55, length=2.2, depth=0.9)
    b.table(2.3, 1.9, 1.0, 0.55, height=0.42, top=0.05)
    b.box(0.25, 2.0, 0.4, 1.6, 0.0, 0.55)
    b.box(4.7, 3.2, 0.4, 0.9, 0.0, 1.9)
    b.plant(0.4, 3.5)
    b.wedge(3.6, 3.3, 0.9, 0.8, 0.18, yaw=math.pi / 2)
    # Kitchen: counters along two walls, an island, a table.
    b.box(7.55, 0.32, 4.7, 0.6, 0.0, 0.9)
    b.box(9.68, 1.8, 0.6, 1.9, 0.0, 0.9)
    b.box(9.68, 3.3, 0.6, 0.7, 0.0, 2.0)  # fridge
    b.box(7.2, 2.2, 1.4, 0.8, 0.0, 0.9)  # island
    b.sphere(6.9, 2.2, 0.98, 0.08)
    # Bedroom.
    b.box(2.0, 8.37, 1.6, 1.94, 0.0, 0.5)  # bed
    b.box(2.0, 9.4, 1.7, 0.12, 0.0, 1.0)  # headboard
    b.box(0.3, 6.6, 0.55, 1.6, 0.0, 2.1)  # wardrobe
    b.box(3.55, 9.2, 0.45, 0.4, 0.0, 0.5)
    # Bathroom.
    b.box(5.3, 8.9, 2.0, 0.9, 0.0, 0.55)  # bath tub
    b.box(6.25, 6.6, 0.45, 0.6, 0.0, 0.85)  # basin unit
    b.cylinder(4.5, 6.3, 0.0, 0.42, 0.2)  # toilet, as clutter
    # Study.
    b.table(8.25, 9.1, 1.6, 0.7)
    b.tilted_panel(8.25, 9.2, 0.85, 0.6, 0.36, yaw=-math.pi / 2, tilt=math.radians(12))
    b.box(9.7, 7.2, 0.45, 1.4, 0.0, 1.8)
    b.cylinder(8.0, 8.3, 0.0, 0.48, 0.26)
    return b.build()


def _corridor(seed: int) -> Scene:
    """A 30 m long, 2 m wide corridor with closed doors in niches on both sides and a few cabinets."""
    b = SceneBuilder("corridor", seed)
    h = 2.7
    box = (0.0, 0.0, 30.0, 2.0)
    left = [(x, DOOR_W, DOOR_H) for x in (3.0, 9.0, 15.0, 21.0, 27.0)]
    right = [(x, DOOR_W, DOOR_H) for x in (6.0, 12.0, 18.0, 24.0)]
    b.room(*box, h, openings={"y-": right, "y+": left})
    for x, _, _ in left:
        b.closed_door("y+", box, x)
    for x, _, _ in right:
        b.closed_door("y-", box, x)
    b.box(7.5, 0.22, 1.0, 0.4, 0.0, 1.1)
    b.box(22.5, 1.78, 1.4, 0.4, 0.0, 0.9)
    b.cylinder(13.5, 1.8, 0.0, 0.6, 0.15)  # fire extinguisher / bin
    b.plant(29.6, 0.4)
    return b.build()


def _meeting_room(b: SceneBuilder, x0: float, y0: float, door_x: float) -> None:
    """One 5 x 4 m meeting room at (x0, y0) whose door is on its y- wall at ``door_x``; all copies identical."""
    h = 2.7
    b.room(x0, y0, x0 + 5.0, y0 + 4.0, h, openings={"y-": [(door_x, DOOR_W, DOOR_H)]})
    b.table(x0 + 2.5, y0 + 2.2, 2.4, 1.1, height=0.74)
    for k in range(3):
        b.cylinder(x0 + 1.7 + 0.8 * k, y0 + 1.3, 0.0, 0.46, 0.22)
        b.cylinder(x0 + 1.7 + 0.8 * k, y0 + 3.1, 0.0, 0.46, 0.22)
    b.box(x0 + 4.75, y0 + 2.0, 0.4, 1.6, 0.0, 0.8)
    b.box(x0 + 0.04, y0 + 2.0, 0.04, 1.4, 0.9, 1.8, obstacle=False)  # screen on the x- wall


def _meeting_rooms(seed: int) -> Scene:
    """Four identical meeting rooms off one corridor: the deliberately ambiguous case."""
    b = SceneBuilder("meeting_rooms", seed)
    h = 2.7
    corr = (0.0, 0.0, 4 * (5.0 + WALL_T) - WALL_T, 2.0)
    doors = [(i * (5.0 + WALL_T) + 1.0, DOOR_W, DOOR_H) for i in range(4)]
    b.room(*corr, h, openings={"y+": doors, "x-": [(1.0, DOOR_W, DOOR_H)]})
    b.closed_door("x-", corr, 1.0)
    for i in range(4):
        x0 = i * (5.0 + WALL_T)
        _meeting_room(b, x0, 2.0 + WALL_T, x0 + 1.0)
        b.doorway("y", 2.0, 2.0 + WALL_T, x0 + 1.0)
    return b.build()


def _symmetric_room(seed: int) -> Scene:
    """A 6 x 6 m room with four-fold symmetry: a closed door mid-wall on every side, a square table in the middle,
    a cabinet in every corner."""
    b = SceneBuilder("symmetric_room", seed)
    h = 2.7
    room = (0.0, 0.0, 6.0, 6.0)
    door = [(3.0, DOOR_W, DOOR_H)]
    b.room(*room, h, openings={s: door for s in ("x-", "x+", "y-", "y+")})
    for s in ("x-", "x+", "y-", "y+"):
        b.closed_door(s, room, 3.0)
    b.table(3.0, 3.0, 1.2, 1.2, height=0.74)
    for k in range(4):
        ang = k * math.pi / 2 + math.pi / 4
        r = math.hypot(2.45, 2.45)
        b.box(3.0 + r * math.cos(ang), 3.0 + r * math.sin(ang), 0.6, 0.6, 0.0, 1.0, yaw=ang)
    return b.build()


def _random_room_contents(b: SceneBuilder, rng: np.random.Generator, room, height) -> None:
    """Random boxes, tables, a ramp, a tilted panel and clutter in ``room``, keeping doorway approaches clear (so
    every room stays reachable). Call after the room's doorways exist."""
    x0, y0, x1, y1 = room
    clear = [(px0 - 0.5, py0 - 0.5, px1 + 0.5, py1 + 0.5) for px0, py0, px1, py1, _ in b.passages]
    # A walkway from each doorway of this room to its centre (an L: across, then along), so furniture never
    # cuts the room in two for a walker with 0.35 m clearance.
    mx, my, hw = (x0 + x1) / 2, (y0 + y1) / 2, 0.45
    for px0, py0, px1, py1, _ in b.passages:
        if px1 < x0 - 0.7 or px0 > x1 + 0.7 or py1 < y0 - 0.7 or py0 > y1 + 0.7:
            continue
        dx, dy = min(max((px0 + px1) / 2, x0), x1), min(max((py0 + py1) / 2, y0), y1)
        clear.append((min(dx, mx) - hw, dy - hw, max(dx, mx) + hw, dy + hw))
        clear.append((mx - hw, min(dy, my) - hw, mx + hw, max(dy, my) + hw))

    def blocked(fx0, fy0, fx1, fy1):
        return any(fx0 < cx1 and fx1 > cx0 and fy0 < cy1 and fy1 > cy0 for cx0, cy0, cx1, cy1 in clear)

    def attempt(draw, tries=20):
        """Draw placements until one misses the doorway zones; None when none did."""
        for _ in range(tries):
            item = draw()
            if not blocked(*item[0]):
                return item
        return None

    def draw_box():
        sx, sy = rng.uniform(0.4, 1.6), rng.uniform(0.35, 0.9)
        if rng.random() < 0.5:
            sx, sy = sy, sx
        # Against a wall (2 cm gap, no z-fighting) or free-standing.
        side = int(rng.integers(0, 5))
        cx = rng.uniform(x0 + sx / 2 + 0.3, x1 - sx / 2 - 0.3)
        cy = rng.uniform(y0 + sy / 2 + 0.3, y1 - sy / 2 - 0.3)
        if side == 0:
            cx = x0 + sx / 2 + 0.02
        elif side == 1:
            cx = x1 - sx / 2 - 0.02
        elif side == 2:
            cy = y0 + sy / 2 + 0.02
        elif side == 3:
            cy = y1 - sy / 2 - 0.02
        is_table = rng.random() < 0.3
        top = float(rng.uniform(0.45, 0.8)) if is_table else float(rng.uniform(0.4, min(2.1, height - 0.3)))
        return (cx - sx / 2, cy - sy / 2, cx + sx / 2, cy + sy / 2), cx, cy, sx, sy, is_table, top

    for _ in range(int(rng.integers(2, 6))):
        item = attempt(draw_box)
        if item is None:
            continue
        _, cx, cy, sx, sy, is_table, top = item
        if is_table:
            b.table(cx, cy, sx, sy, height=top)
        else:
            b.box(cx, cy, sx, sy, 0.0, top)

    def draw_disc(margin, r):
        x, y = rng.uniform(x0 + margin, x1 - margin), rng.uniform(y0 + margin, y1 - margin)
        return (x - r, y - r, x + r, y + r), x, y

    if rng.random() < 0.6:
        rise, yaw = float(rng.uniform(0.1, 0.3)), float(rng.uniform(0, 2 * math.pi))
        item = attempt(lambda: draw_disc(1.0, math.hypot(0.5, 0.4)))
        if item is not None:
            b.wedge(item[1], item[2], 1.0, 0.8, rise, yaw=yaw)
    if rng.random() < 0.5:
        z, yaw, tilt = float(rng.uniform(0.3, 1.0)), float(rng.uniform(0, 2 * math.pi)), float(rng.uniform(0.1, 0.5))
        item = attempt(lambda: draw_disc(1.0, 0.45))
        if item is not None:
            b.tilted_panel(item[1], item[2], z, 0.8, 0.6, yaw=yaw, tilt=tilt)
            b.obstacles.append(item[0])
    for _ in range(int(rng.integers(1, 4))):
        is_cyl = rng.random() < 0.5
        r = float(rng.uniform(0.08, 0.3)) if is_cyl else float(rng.uniform(0.1, 0.3))
        top = float(rng.uniform(0.3, 1.2))
        item = attempt(lambda: draw_disc(0.4, r))
        if item is None:
            continue
        if is_cyl:
            b.cylinder(item[1], item[2], 0.0, top, r)
        else:
            b.sphere(item[1], item[2], r, r)


def _random(seed: int) -> Scene:
    """A seeded random flat: 2-4 rooms in a row joined by doorways, random furniture, ramps, panels and clutter."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0x5CE7E]))
    b = SceneBuilder("random", seed)
    h = float(rng.uniform(2.4, 3.0))
    n_rooms = int(rng.integers(2, 5))
    depth_y = float(rng.uniform(3.5, 6.0))
    widths = rng.uniform(3.5, 6.5, size=n_rooms)
    x = 0.0
    rects = []
    for w in widths:
        rects.append((x, 0.0, x + float(w), depth_y))
        x += float(w) + WALL_T
    door_y = [float(rng.uniform(0.8, depth_y - 0.8)) for _ in range(n_rooms - 1)]
    for i, r in enumerate(rects):
        openings = {}
        if i > 0:
            openings["x-"] = [(door_y[i - 1], DOOR_W, DOOR_H)]
        if i < n_rooms - 1:
            openings["x+"] = [(door_y[i], DOOR_W, DOOR_H)]
        b.room(*r, h, openings=openings)
    for i in range(n_rooms - 1):
        b.doorway("x", rects[i][2], rects[i + 1][0], door_y[i])
    for r in rects:
        _random_room_contents(b, rng, r, h)
    return b.build()


def _building(seed: int) -> Scene:
    """A floor of an office building: two long corridors with 14 furnished rooms each (1,000+ planes)."""
    rng = np.random.default_rng(np.random.SeedSequence([seed, 0xB111D]))
    b = SceneBuilder("building", seed)
    h = 2.8
    n_per_side = 9
    room_w = 5.0
    length = n_per_side * (room_w + WALL_T) - WALL_T
    corridors = []
    for wing in range(2):
        y_base = wing * (2 * 5.0 + 2.4 + 4 * WALL_T + 3.0)
        corr = (0.0, y_base + 5.0 + WALL_T, length, y_base + 5.0 + WALL_T + 2.4)
        south_doors, north_doors = [], []
        for i in range(n_per_side):
            x0 = i * (room_w + WALL_T)
            dx = x0 + float(rng.uniform(0.8, room_w - 0.8))
            south = (x0, y_base, x0 + room_w, y_base + 5.0)
            b.room(*south, h, openings={"y+": [(dx, DOOR_W, DOOR_H)]})
            b.doorway("y", south[3], corr[1], dx)
            south_doors.append((dx, DOOR_W, DOOR_H))
            _random_room_contents(b, rng, south, h)
            dx = x0 + float(rng.uniform(0.8, room_w - 0.8))
            north = (x0, corr[3] + WALL_T, x0 + room_w, corr[3] + WALL_T + 5.0)
            b.room(*north, h, openings={"y-": [(dx, DOOR_W, DOOR_H)]})
            b.doorway("y", corr[3], north[1], dx)
            north_doors.append((dx, DOOR_W, DOOR_H))
            _random_room_contents(b, rng, north, h)
        b.room(*corr, h, openings={"y-": south_doors, "y+": north_doors, "x-": [(corr[1] + 1.2, DOOR_W, DOOR_H)],
                                   "x+": [((corr[1] + corr[3]) / 2, 1.2, DOOR_H)]})
        b.closed_door("x-", corr, corr[1] + 1.2)
        corridors.append(corr)
    # A hall along the east end joins the two wings' corridors.
    c0, c1 = corridors
    link = (length + WALL_T, c0[1], length + WALL_T + 2.4, c1[3])
    mids = [((c[1] + c[3]) / 2, 1.2, DOOR_H) for c in corridors]
    b.room(*link, h, openings={"x-": mids})
    for yc, w, _ in mids:
        b.doorway("x", length, link[0], yc, width=w)
    return b.build()


_FACTORIES = {
    "living_room": _living_room,
    "office": _office,
    "apartment": _apartment,
    "corridor": _corridor,
    "meeting_rooms": _meeting_rooms,
    "symmetric_room": _symmetric_room,
    "random": _random,
    "building": _building,
}


def make_scene(name: str, seed: int = 0) -> Scene:
    """The scene ``name`` (one of :data:`SCENE_NAMES`); ``seed`` only changes ``random`` and ``building``."""
    if name not in _FACTORIES:
        raise ValueError(f"name: expected one of {', '.join(SCENE_NAMES)}, got {name!r}")
    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed: expected a non-negative integer, got {seed!r}")
    return _FACTORIES[name](int(seed))
