"""A large single-object "cathedral" for issue #11: bpy-free arrays of what a cathedral has.

Rows of columns with capitals, bases and carved rosettes; round arches with
undersides between them; nave walls with an inside and an outside; an apse
(half cylinder and half dome); stairs up to a raised choir; stacked mouldings
along the walls; thin parapets on top; window tracery (rings and mullions) in
the wall planes. Everything is one mesh of quads and n-gons (column caps,
rosette centres), as a user's imported model would be: 124k triangles at the
default ``detail=0.8``, 18k at ``detail=0.2``. Units are metres, Z up.

``python tests/cathedral.py [detail] [resolution]`` unwraps it and prints the
overlap count of the light-map layout (must be 0).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PolygonMesh:
    """positions (V, 3) float64 metres; face_vertices (sum of counts,) int64 vertex indices;
    face_counts (F,) int64 corners per face (3 or more)."""

    positions: np.ndarray
    face_vertices: np.ndarray
    face_counts: np.ndarray

    def faces(self) -> list:
        """Faces as tuples of vertex indices (``Mesh.from_pydata``)."""
        ends = np.cumsum(self.face_counts)
        return [tuple(v) for v in np.split(self.face_vertices, ends[:-1])]

    def triangles(self) -> tuple[np.ndarray, np.ndarray]:
        """Fan triangulation: (triangles (t, 3) int64, polygon (t,) int64)."""
        starts = np.cumsum(self.face_counts) - self.face_counts
        fans = self.face_counts - 2
        polygon = np.repeat(np.arange(len(self.face_counts)), fans)
        k = np.arange(int(fans.sum())) - np.repeat(np.cumsum(fans) - fans, fans)
        first = starts[polygon]
        tri = np.stack([self.face_vertices[first], self.face_vertices[first + k + 1],
                        self.face_vertices[first + k + 2]], axis=1)
        return tri, polygon


class _Builder:
    def __init__(self):
        self.points: list = []
        self.faces: list = []
        self.count = 0

    def add(self, points, faces):
        points = np.asarray(points, np.float64).reshape(-1, 3)
        self.points.append(points)
        self.faces += [tuple(int(v) + self.count for v in f) for f in faces]
        self.count += len(points)

    def grid(self, surface, nu, nv, closed_u=False):
        """Quads over ``surface(u, v) -> (..., 3)`` for u, v in [0, 1]; u wraps when closed."""
        cols = nu if closed_u else nu + 1
        u = np.arange(cols) / nu
        v = np.linspace(0.0, 1.0, nv + 1)
        uu, vv = np.meshgrid(u, v)
        points = surface(uu, vv).reshape(-1, 3)
        faces = []
        for j in range(nv):
            for i in range(nu):
                i1 = (i + 1) % cols
                faces.append((j * cols + i, j * cols + i1, (j + 1) * cols + i1, (j + 1) * cols + i))
        self.add(points, faces)

    def box(self, lo, hi):
        (x0, y0, z0), (x1, y1, z1) = lo, hi
        points = [(x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0),
                  (x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)]
        self.add(points, [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)])

    def revolve(self, centre, profile, segments, caps=True):
        """Surface of revolution of ``profile`` [(r, z), ...] around a vertical axis, with
        n-gon caps at the ends (column shafts, capitals, bases)."""
        r = np.array([p[0] for p in profile])
        z = np.array([p[1] for p in profile])
        cx, cy, cz = centre

        def surface(u, v):
            idx = v * (len(profile) - 1)
            radius = np.interp(idx, np.arange(len(profile)), r)
            height = np.interp(idx, np.arange(len(profile)), z)
            a = 2 * math.pi * u
            return np.stack([cx + radius * np.cos(a), cy + radius * np.sin(a), cz + height], -1)

        base = self.count
        self.grid(surface, segments, len(profile) - 1, closed_u=True)
        if caps:
            self.faces.append(tuple(base + i for i in reversed(range(segments))))
            top = base + (len(profile) - 1) * segments
            self.faces.append(tuple(top + i for i in range(segments)))


def _column(b, x, y, detail):
    seg = max(8, int(40 * detail))
    rings = max(4, int(30 * detail))
    shaft = [(0.35 + 0.01 * math.sin(4 * math.pi * k / rings), 0.6 + 5.4 * k / rings) for k in range(rings + 1)]
    b.revolve((x, y, 0.0), [(0.55, 0.0), (0.55, 0.25), (0.45, 0.35), (0.4, 0.5), (0.36, 0.6)], seg)  # base
    b.revolve((x, y, 0.0), shaft, seg, caps=False)
    capital = [(0.36, 6.0), (0.42, 6.2), (0.55, 6.45), (0.62, 6.6), (0.62, 6.75)]
    b.revolve((x, y, 0.0), capital, seg)
    for k in range(4):  # carved rosettes on the capital
        a = k * math.pi / 2
        _rosette(b, (x + 0.6 * math.cos(a), y + 0.6 * math.sin(a), 6.45), a, detail)


def _rosette(b, centre, angle, detail):
    """A small carved flower: a bumpy disc facing outwards, an n-gon at its heart."""
    n = max(8, int(24 * detail))
    rings = max(3, int(10 * detail))
    cx, cy, cz = centre
    d = np.array([math.cos(angle), math.sin(angle), 0.0])
    t = np.array([-math.sin(angle), math.cos(angle), 0.0])
    up = np.array([0.0, 0.0, 1.0])

    def surface(u, v):
        a = 2 * math.pi * u
        radius = 0.03 + 0.09 * v * (1 + 0.25 * np.cos(6 * a))
        bulge = 0.04 * np.sin(math.pi * v)
        return (np.array([cx, cy, cz]) + radius[..., None] * (np.cos(a)[..., None] * t + np.sin(a)[..., None] * up)
                + bulge[..., None] * d)

    base = b.count
    b.grid(surface, n, rings, closed_u=True)
    b.faces.append(tuple(base + i for i in range(n)))


def _arch(b, x0, x1, y, z_spring, depth, detail):
    """A round arch between two capitals: front and back faces, the underside (intrados)
    and the top (extrados), as one closed band."""
    seg = max(8, int(32 * detail))
    r_in = (x1 - x0) / 2
    r_out = r_in + 0.45
    xc = (x0 + x1) / 2

    def ring(radius, yy):
        return lambda u, v: np.stack([xc - radius * np.cos(math.pi * u), yy + 0 * u,
                                      z_spring + radius * np.sin(math.pi * u)], -1)

    def band(r0, r1, y0, y1):
        def surface(u, v):
            radius = r0 + (r1 - r0) * v
            yy = y0 + (y1 - y0) * v
            return np.stack([xc - radius * np.cos(math.pi * u), yy, z_spring + radius * np.sin(math.pi * u)], -1)
        return surface

    h = depth / 2
    b.grid(band(r_in, r_out, y - h, y - h), seg, 2)  # front
    b.grid(band(r_out, r_in, y + h, y + h), seg, 2)  # back
    b.grid(band(r_in, r_in, y + h, y - h), seg, max(2, int(6 * detail)))  # underside
    b.grid(band(r_out, r_out, y - h, y + h), seg, 2)  # top


def _wall(b, x0, x1, y, z0, z1, thickness, detail, windows):
    """A nave wall with an inside and an outside face, end caps, a parapet and tracery."""
    nu, nv = max(8, int(80 * detail)), max(4, int(24 * detail))
    for yy, (xa, xb) in ((y, (x0, x1)), (y + sign_of(y) * thickness, (x1, x0))):  # inside, outside
        b.grid(lambda u, v, yy=yy, xa=xa, xb=xb: np.stack([xa + (xb - xa) * u, yy + 0 * u, z0 + (z1 - z0) * v], -1),
               nu, nv)
    lo, hi = min(y, y + sign_of(y) * thickness), max(y, y + sign_of(y) * thickness)
    b.box((x0 - 0.01, lo, z1), (x1 + 0.01, hi, z1 + 0.02))  # the wall's top
    b.box((x0, lo - 0.01, z1 + 0.02), (x1, lo + 0.02, z1 + 0.9))  # a thin parapet (3 cm)
    for k in range(4):  # stacked mouldings: boxes resting on each other
        z = 7.0 + 0.12 * k
        out = 0.08 + 0.04 * k  # each one sticks out further into the nave than the one below
        b.box((x0, y - out, z), (x1, y, z + 0.12)) if y > 0 else b.box((x0, y, z), (x1, y + out, z + 0.12))
    for wx in windows:
        _tracery(b, wx, y, 9.5, detail)


def sign_of(y):
    return 1.0 if y >= 0 else -1.0


def _tracery(b, x, y, z, detail):
    """A window's tracery just inside the wall plane: a ring and three mullions."""
    seg = max(8, int(48 * detail))
    yy = y - 0.05 * sign_of(y)

    def torus(R, r):
        def surface(u, v):
            a, c = 2 * math.pi * u, 2 * math.pi * v
            return np.stack([x + (R + r * np.cos(c)) * np.cos(a), yy + r * np.sin(c) + 0 * a,
                             z + (R + r * np.cos(c)) * np.sin(a)], -1)
        return surface

    b.grid(torus(0.8, 0.04), seg, max(4, int(8 * detail)), closed_u=True)
    b.grid(torus(0.35, 0.03), seg, max(4, int(8 * detail)), closed_u=True)
    for dx in (-0.4, 0.0, 0.4):
        b.box((x + dx - 0.03, yy - 0.03, z - 1.6), (x + dx + 0.03, yy + 0.03, z - 0.1))


def _apse(b, x, radius, height, detail):
    """A half-cylinder wall (inside and outside) and a half dome closing the nave at ``x``."""
    seg, rows = max(8, int(64 * detail)), max(4, int(24 * detail))
    for r in (radius, radius + 0.6):
        b.grid(lambda u, v, r=r: np.stack([x + r * np.sin(math.pi * u), -r * np.cos(math.pi * u),
                                           height * v], -1), seg, rows)
    b.grid(lambda u, v: np.stack([x + radius * np.sin(math.pi * u) * np.cos(0.5 * math.pi * v),
                                  -radius * np.cos(math.pi * u) * np.cos(0.5 * math.pi * v),
                                  height + radius * np.sin(0.5 * math.pi * v)], -1), seg, max(4, int(16 * detail)))


def _stairs(b, x0, width, steps, run=0.3, rise=0.18):
    """A solid flight standing on the floor: treads, risers, two flanks and a back, no face on another.

    Not a pile of boxes: their flanks would lie in one plane, overlapping, where no renderer's answer
    is right (Cycles' shadow rays hit the coplanar twin and black the flank out)."""
    y0, y1 = -width / 2, width / 2
    for k in range(steps):
        xa, xb, low, h = x0 + run * k, x0 + run * (k + 1), rise * k, rise * (k + 1)
        b.add([(xa, y0, h), (xb, y0, h), (xb, y1, h), (xa, y1, h)], [(0, 1, 2, 3)])  # tread, up
        b.add([(xa, y1, low), (xa, y0, low), (xa, y0, h), (xa, y1, h)], [(0, 1, 2, 3)])  # riser, -x
        b.add([(xa, y0, 0.0), (xb, y0, 0.0), (xb, y0, h), (xa, y0, h)], [(0, 1, 2, 3)])  # flank, -y
        b.add([(xb, y1, 0.0), (xa, y1, 0.0), (xa, y1, h), (xb, y1, h)], [(0, 1, 2, 3)])  # flank, +y
    x1, top = x0 + run * steps, rise * steps
    b.add([(x1, y0, 0.0), (x1, y1, 0.0), (x1, y1, top), (x1, y0, top)], [(0, 1, 2, 3)])  # back, +x


DEFAULT_DETAIL = 0.8


def cathedral(detail: float = DEFAULT_DETAIL) -> PolygonMesh:
    """The cathedral as one polygon mesh (124k triangles at the default detail)."""
    b = _Builder()
    bays = 10
    span = 4.0
    length = bays * span
    b.grid(lambda u, v: np.stack([-2 + (length + 4) * u, -9 + 18 * v, 0 * u], -1),
           max(8, int(90 * detail)), max(4, int(36 * detail)))  # floor
    for side in (-1, 1):
        for k in range(bays + 1):
            _column(b, k * span, side * 4.0, detail)
        for k in range(bays):
            _arch(b, k * span + 0.6, (k + 1) * span - 0.6, side * 4.0, 6.75, 0.8, detail)
        windows = [k * span + span / 2 for k in range(bays)]
        _wall(b, -2.0, length, side * 8.0, 0.0, 12.0, 0.8, detail, windows)
    _apse(b, length, 8.0, 12.0, detail)
    _stairs(b, length - 3.0, 6.0, 6)
    counts = np.array([len(f) for f in b.faces], np.int64)
    return PolygonMesh(np.concatenate(b.points), np.fromiter((v for f in b.faces for v in f), np.int64), counts)


def main(argv) -> None:
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    import pdic_bootstrap

    pdic_bootstrap.load()
    from pdic.core.unwrap import unwrap
    from pdic.core.uv_overlap import uv_overlaps

    detail = float(argv[1]) if len(argv) > 1 else DEFAULT_DETAIL
    resolution = int(argv[2]) if len(argv) > 2 else 1024
    mesh = cathedral(detail)
    tri, polygon = mesh.triangles()
    r = unwrap(mesh.positions, tri, resolution, 2, triangle_polygon=polygon, max_resolution=4096)
    print(f"cathedral detail {detail}: {len(tri)} triangles, {len(mesh.face_counts)} faces; unwrap at "
          f"{r.resolution}^2: {r.chart_count} charts, utilization {r.utilization:.3f}, polygons fixed "
          f"{r.polygons_fixed}, detached {r.polygons_detached}; overlapping texel centres "
          f"{uv_overlaps(r.uv, None, r.resolution, r.resolution)}")


if __name__ == "__main__":
    import sys

    main(sys.argv)
