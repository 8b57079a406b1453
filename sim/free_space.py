"""Where a robot or a person can stand in a scene, and a roadmap of collision-free paths through it.

Free space is 2-D (the floor plan): inside a room rectangle shrunk by the clearance, or inside a doorway passage
(shrunk across its width only), and at least the clearance away from every furniture or clutter footprint.
"""

from __future__ import annotations

import heapq

import numpy as np

from sim.scenes import Scene

__all__ = ["is_free", "segment_free", "sample_free", "Roadmap"]


def is_free(scene: Scene, xy: np.ndarray, clearance_m: float = 0.3) -> np.ndarray:
    """(N,) bool: the points ``xy`` (N, 2) are in free space with ``clearance_m`` to walls and obstacles."""
    p = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    x, y = p[:, :1], p[:, 1:]
    c = clearance_m
    r = scene.rooms
    inside = np.any((x >= r[:, 0] + c) & (x <= r[:, 2] - c) & (y >= r[:, 1] + c) & (y <= r[:, 3] - c), axis=1)
    if scene.passages.shape[0]:
        ps = scene.passages
        along_x = ps[:, 4] == 0
        cx = np.where(along_x, 0.0, c)
        cy = np.where(along_x, c, 0.0)
        in_p = (x >= ps[:, 0] + cx) & (x <= ps[:, 2] - cx) & (y >= ps[:, 1] + cy) & (y <= ps[:, 3] - cy)
        inside |= np.any(in_p, axis=1)
    if scene.obstacles.shape[0]:
        o = scene.obstacles
        hit = np.any((x > o[:, 0] - c) & (x < o[:, 2] + c) & (y > o[:, 1] - c) & (y < o[:, 3] + c), axis=1)
        inside &= ~hit
    return inside


def segment_free(scene: Scene, a: np.ndarray, b: np.ndarray, clearance_m: float = 0.3, step_m: float = 0.05) -> bool:
    """True when the straight segment from ``a`` to ``b`` (2-D) stays in free space (checked every ``step_m``)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    n = max(2, int(np.ceil(np.linalg.norm(b - a) / step_m)) + 1)
    t = np.linspace(0.0, 1.0, n)[:, None]
    return bool(np.all(is_free(scene, a + t * (b - a), clearance_m)))


def sample_free(scene: Scene, rng: np.random.Generator, n: int, clearance_m: float = 0.3,
                max_tries: int = 200) -> np.ndarray:
    """(n, 2) points drawn uniformly from the free space (rejection sampling over the room rectangles)."""
    rooms = scene.rooms
    areas = (rooms[:, 2] - rooms[:, 0]) * (rooms[:, 3] - rooms[:, 1])
    out = np.zeros((0, 2))
    for _ in range(max_tries):
        k = max(8, 2 * (n - len(out)))
        which = rng.choice(len(rooms), size=k, p=areas / areas.sum())
        pts = np.column_stack([rng.uniform(rooms[which, 0], rooms[which, 2]),
                               rng.uniform(rooms[which, 1], rooms[which, 3])])
        out = np.concatenate([out, pts[is_free(scene, pts, clearance_m)]])
        if len(out) >= n:
            return out[:n]
    raise ValueError(f"scene {scene.name!r}: could not find {n} free points with clearance {clearance_m} m")


class Roadmap:
    """A probabilistic roadmap: free sample points (plus the doorway centres) joined by collision-free edges."""

    def __init__(self, scene: Scene, rng: np.random.Generator, clearance_m: float = 0.3,
                 n_nodes: int | None = None, k_neighbours: int = 12, max_edge_m: float = 4.0) -> None:
        self.scene = scene
        self.clearance_m = clearance_m
        rooms = scene.rooms
        area = float(((rooms[:, 2] - rooms[:, 0]) * (rooms[:, 3] - rooms[:, 1])).sum())
        n = n_nodes or int(np.clip(3 * area, 40, 4000))
        nodes = [sample_free(scene, rng, n, clearance_m)]
        # Doorways: their centre and a point on either side, so paths between rooms exist.
        for x0, y0, x1, y1, axis in scene.passages:
            cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
            half = ((x1 - x0) if axis == 0 else (y1 - y0)) / 2
            d = np.array([1.0, 0.0]) if axis == 0 else np.array([0.0, 1.0])
            cand = np.array([[cx, cy], [cx, cy] + d * half * 0.9, [cx, cy] - d * half * 0.9])
            nodes.append(cand[is_free(scene, cand, clearance_m)])
        self.nodes = np.concatenate(nodes)
        m = len(self.nodes)
        self.adj: list[list[tuple[int, float]]] = [[] for _ in range(m)]
        k = min(k_neighbours, m - 1)
        for i in range(m):
            dist = np.linalg.norm(self.nodes - self.nodes[i], axis=1)
            near = np.argpartition(dist, k)[: k + 1]
            for j in near[np.argsort(dist[near])]:
                j = int(j)
                if j == i or dist[j] > max_edge_m or any(q == j for q, _ in self.adj[i]):
                    continue
                if segment_free(scene, self.nodes[i], self.nodes[j], clearance_m):
                    self.adj[i].append((j, float(dist[j])))
                    self.adj[j].append((i, float(dist[j])))
        self.component = self._components()

    def _components(self) -> np.ndarray:
        comp = -np.ones(len(self.nodes), dtype=np.int64)
        c = 0
        for s in range(len(self.nodes)):
            if comp[s] >= 0:
                continue
            stack = [s]
            comp[s] = c
            while stack:
                i = stack.pop()
                for j, _ in self.adj[i]:
                    if comp[j] < 0:
                        comp[j] = c
                        stack.append(j)
            c += 1
        return comp

    def largest_component(self) -> np.ndarray:
        """Indices of the nodes of the largest connected component."""
        counts = np.bincount(self.component)
        return np.flatnonzero(self.component == int(np.argmax(counts)))

    def shortest_path(self, start: int, goal: int) -> list[int]:
        """Node indices from ``start`` to ``goal`` (Dijkstra); empty when they are not connected."""
        dist = {start: 0.0}
        prev: dict[int, int] = {}
        heap = [(0.0, start)]
        while heap:
            d, i = heapq.heappop(heap)
            if i == goal:
                break
            if d > dist.get(i, np.inf):
                continue
            for j, w in self.adj[i]:
                nd = d + w
                if nd < dist.get(j, np.inf):
                    dist[j] = nd
                    prev[j] = i
                    heapq.heappush(heap, (nd, j))
        if goal not in dist:
            return []
        path = [goal]
        while path[-1] != start:
            path.append(prev[path[-1]])
        return path[::-1]

    def room_tour(self, rng: np.random.Generator, min_length_m: float) -> np.ndarray:
        """(K, 2) waypoints of a tour that enters every room: in each round, the nearest room not yet entered
        (by its centre) next, a random node of it the goal of a shortest path; round after round until the tour is
        at least ``min_length_m`` long. What a mapping run does that must leave no room out; a room without a node
        in the largest component (none of the scenes here) is left out."""
        comp = self.largest_component()
        if len(comp) < 2:
            raise ValueError(f"scene {self.scene.name!r}: free space too small for a trajectory")
        xy = self.nodes[comp]
        inside = [comp[(xy[:, 0] > x0) & (xy[:, 0] < x1) & (xy[:, 1] > y0) & (xy[:, 1] < y1)]
                  for x0, y0, x1, y1, _ in self.scene.rooms]
        keep = [k for k, nodes in enumerate(inside) if len(nodes)]
        inside = [inside[k] for k in keep]
        centres = np.array([[(r[0] + r[2]) / 2, (r[1] + r[3]) / 2] for r in self.scene.rooms[keep]])
        cur = int(rng.choice(comp))
        pts = [self.nodes[cur]]
        length = 0.0
        while length < min_length_m:
            left = list(range(len(inside)))
            goals = []
            while left:
                r = left.pop(int(np.argmin(np.linalg.norm(centres[left] - self.nodes[goals[-1] if goals else cur],
                                                           axis=1))))
                goals.append(int(rng.choice(inside[r])))
            if all(g == cur for g in goals):  # one room of one node: anywhere else, then back
                goals.insert(0, int(rng.choice(comp[comp != cur])))
            for goal in goals:
                if goal == cur or length >= min_length_m:
                    continue
                for j in self.shortest_path(cur, goal)[1:]:
                    length += float(np.linalg.norm(self.nodes[j] - pts[-1]))
                    pts.append(self.nodes[j])
                cur = goal
        return np.array(pts)

    def random_walk(self, rng: np.random.Generator, min_length_m: float) -> np.ndarray:
        """(K, 2) waypoints of a tour through the largest component: shortest paths to random goals, chained,
        until the tour is at least ``min_length_m`` long."""
        comp = self.largest_component()
        if len(comp) < 2:
            raise ValueError(f"scene {self.scene.name!r}: free space too small for a trajectory")
        cur = int(rng.choice(comp))
        pts = [self.nodes[cur]]
        length = 0.0
        while length < min_length_m:
            goal = int(rng.choice(comp))
            if goal == cur:
                continue
            path = self.shortest_path(cur, goal)
            for j in path[1:]:
                length += float(np.linalg.norm(self.nodes[j] - pts[-1]))
                pts.append(self.nodes[j])
            cur = goal
        return np.array(pts)
