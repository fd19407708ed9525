"""Texel samples on a face that another face touches, face to face (deviation: contact-faces).

A building standing on a ground plane, a cabinet's back flush against a wall made of one face:
two faces lie in one plane and face each other. Rays leave a surface :attr:`RayCaster.epsilon`
off it, so a sample's rays start past the face it touches, in the open beyond (under a ground
plane: the sky below the horizon), and light reaches it where none can; Cycles' rays leave the
surface itself and meet the touching face at once. Such samples count as covered
(:mod:`core.validity`: no indirect light, no sky, no hole record) and get no direct light.

Only a face that is the skin of a solid counts (a ray from the sample into its back meets a back
face, the solid's inside): two open sheets back to back, a wall of two faces each lit by its own
room, touch the same way but are one surface seen from two sides, and Cycles darkening both is its
self-intersection rule, not light (as for faces duplicated in place, bench/coincident.py); so are a
face and its own copy turned over (a sheet made two-sided by a flipped duplicate).

Only triangles whose plane another triangle shares facing the other way are asked: one short ray
per sample on them, against a BVH of the triangles facing the other way, so a sample's own
triangle is never in the way, and one ray into the back of those that touch.

A sample *under a sheet* (deviation: under-sheets) is one a face nearly parallel to its own lies over,
nearer than the rays' offset: a decal 80 um over its wall, a slab's face a hair above another. Its rays
start past the sheet, in the open; Cycles' meet the sheet (its back, or its front) at once. Such a sheet
need not touch the face nor bound a solid, and its normal may be a degree or two off, which no plane hash
finds: every sample is asked, with one ray down its normal through the offset.
"""
from __future__ import annotations

import copy
import functools
import threading
import weakref

import numpy as np

from .constants import COVERED_COS
from .executor import row_chunks
from .rays import RayCaster

CONTACT_EPSILONS = 2.0
"""How far off a sample's plane (in :attr:`RayCaster.epsilon`, the rays' offset) a touching face may lie."""
CONTACT_COS = 0.999
"""A touching face's normal is within 2.6 degrees of the sample's, reversed."""
NORMAL_STEP = 1e-3
"""Unit normals are grouped into planes on this grid (faces a few hundredths of a degree apart share one)."""
_CANONICAL = np.array([0.5773502691896258, 0.5772, 0.5775])
"""A direction no modelled normal is perpendicular to: the sign of n . it tells a face from its reverse."""
SHEET_NEAREST = 0.05
"""A face nearer than this many ray offsets over a sample lies in its plane (its own triangle, a coplanar
neighbour, a copy in place, each within float32 rounding, about 1e-7 of the scene): not a sheet over it."""
SHEET_FARTHEST = 2.0
"""Sheets are looked for up to this many offsets over a sample; past one its own rays meet them (texel
validity's back-face vote, or covered)."""


class ContactFaces:
    """The triangles of a scene that may touch another face to face, and the BVHs to test samples on them.

    positions : (T, 3, 3) scene-local corners (``Geometry.positions``); caster : the bake's
    :class:`RayCaster` over them (its extent, epsilon and face normals).
    touch : test for faces that touch face to face (deviation: contact-faces).
    sheets : test for sheets over the samples (deviation: under-sheets).
    """

    def __init__(self, positions: np.ndarray, caster: RayCaster, touch: bool = True, sheets: bool = True):
        self.caster = caster
        self.face_normals = caster.face_normals
        self.solid_rays = 0
        """The skin and sheet tests' rays (the touch tests' are counted by their BVHs)."""
        self.epsilon = caster.epsilon
        self.sheets = sheets
        self._sheet_verdicts = {}  # id(p) -> (weakref to p, triangle, verdicts): shared with the views
        self._sheet_lock = threading.RLock()  # re-entered when a weakref's callback runs inside the test
        sign, candidate = touching_planes(positions, self.face_normals, CONTACT_EPSILONS * caster.epsilon)
        self.sign = np.where(candidate & touch, sign, 0).astype(np.int8)
        """(T,) +1 / -1: the triangle may touch a face of the other sign; 0: it touches none."""
        self._casters = {}
        for s in (1, -1):
            members = np.flatnonzero(self.sign == s)
            if len(members):
                self._casters[s] = (members, RayCaster(positions[members], caster.extent))

    def view(self) -> "ContactFaces":
        """These tests for another thread: the same BVHs, rays counted apart (:meth:`absorb` adds them back),
        so two stages that test samples at once keep exact counts."""
        view = copy.copy(self)
        view.solid_rays = 0
        view._casters = {s: (members, caster.serial()) for s, (members, caster) in self._casters.items()}
        return view

    def absorb(self, view: "ContactFaces") -> None:
        """Count the rays a :meth:`view` of these tests cast as these tests' own, each where it belongs."""
        self.solid_rays += view.solid_rays
        for s, (_, caster) in view._casters.items():
            self._casters[s][1].rays_cast += caster.rays_cast

    @property
    def any(self) -> bool:
        return len(self._casters) == 2

    @property
    def rays_cast(self) -> int:
        """Rays the tests cast so far (statistics: ``contact_rays``)."""
        return self.solid_rays + sum(caster.rays_cast for _, caster in self._casters.values())

    def samples(self, p: np.ndarray, triangle: np.ndarray) -> np.ndarray:
        """(m,) bool: which samples at p (m, 3) on ``triangle`` (m,) no light reaches: :meth:`touching`
        or :meth:`under_sheet`."""
        return self.touching(p, triangle) | self.under_sheet(p, triangle)

    def touching(self, p: np.ndarray, triangle: np.ndarray) -> np.ndarray:
        """(m,) bool: which samples at p (m, 3) on ``triangle`` (m,) touch another face, face to face, on
        a face that is the skin of a solid (deviation: contact-faces)."""
        return self._skin(p, triangle, self._touch(p, triangle))

    def under_sheet(self, p: np.ndarray, triangle: np.ndarray) -> np.ndarray:
        """(m,) bool: which samples at p (m, 3) on ``triangle`` (m,) a face nearly parallel to theirs
        (COVERED_COS, facing either way) and opaque lies over, between SHEET_NEAREST and SHEET_FARTHEST
        ray offsets (deviation: under-sheets). The ray runs down the sample's normal from the far end, so the
        sample's own face and the faces in its plane lie past its reach; a face across the ray at a
        steeper angle is a crease or an intersection beside the sample, which its own rays judge."""
        under = np.zeros(len(p), bool)
        if not self.sheets or len(p) == 0:
            return under
        # A target's samples are asked twice, for direct light and for validity, often at once on two
        # threads: the second waits for the first's verdicts (the same rays, counted once).
        with self._sheet_lock:
            known = self._sheet_verdicts.get(id(p))
            if known is not None and known[0]() is p and known[1] is triangle:
                return known[2].copy()
            under = self._under_sheet(p, triangle)
            forget = functools.partial(_forget, self._sheet_verdicts, self._sheet_lock, id(p))
            self._sheet_verdicts[id(p)] = (weakref.ref(p, forget), triangle, under.copy())
        return under

    def _under_sheet(self, p: np.ndarray, triangle: np.ndarray) -> np.ndarray:
        """:meth:`under_sheet`'s rays, in passes of ROW_CHUNK samples."""
        under = np.zeros(len(p), bool)
        caster = self.caster.serial()
        top = SHEET_FARTHEST * self.epsilon
        for s in row_chunks(len(p)):
            n = np.take(self.face_normals, triangle[s], axis=0)
            hits = caster.intersect(p[s] + top * n, -n, t_max=top - SHEET_NEAREST * self.epsilon, unit=True)
            hit = np.flatnonzero(hits.hit)
            sheet = hits.triangle[hit]
            facing = np.einsum("ij,ij->i", np.take(self.face_normals, sheet, axis=0), n[hit])
            opaque = True if self.caster.transmission is None else self.caster.transmission[sheet] == 0
            # light passes a sheet that lets it through
            under[s][hit[(np.abs(facing) >= COVERED_COS) & opaque]] = True
        self.solid_rays += len(p)
        return under

    def _touch(self, p: np.ndarray, triangle: np.ndarray) -> np.ndarray:
        """(m,) bool: which points p (m, 3) on ``triangle`` (m,) another face touches, face to face."""
        touching = np.zeros(len(p), bool)
        if not self.any:
            return touching
        for s, (members, caster) in self._casters.items():
            ask = np.flatnonzero(np.take(self.sign, triangle) == -s)
            if len(ask) == 0:
                continue
            n = np.take(self.face_normals, triangle[ask], axis=0)
            reach = CONTACT_EPSILONS * self.epsilon
            hits = caster.intersect(p[ask] - reach * n, n, t_max=2.0 * reach, unit=True)
            hit = np.flatnonzero(hits.hit)
            facing = np.einsum("ij,ij->i", np.take(self.face_normals, members[hits.triangle[hit]], axis=0), n[hit])
            touching[ask[hit[facing < -CONTACT_COS]]] = True
        return touching

    def _skin(self, p: np.ndarray, triangle: np.ndarray, touching: np.ndarray) -> np.ndarray:
        """``touching`` (m,) less the samples whose face bounds no solid: a ray into the face's back meets
        no back face (it leaves into open space or meets another room's front faces). Where the ray meets
        two faces that touch (a pillar's bottom on the ground, seen from inside the pillar), it meets the
        back face among them, whichever of the two Embree reports."""
        ask = np.flatnonzero(touching)
        if len(ask) == 0:
            return touching
        n = np.take(self.face_normals, triangle[ask], axis=0)
        hits = self.caster.serial().intersect(p[ask], -n, normals=n, unit=True)
        self.solid_rays += len(ask)
        hit = np.flatnonzero(hits.hit)
        inside = np.zeros(len(ask), bool)
        back = np.einsum("ij,ij->i", np.take(self.face_normals, hits.triangle[hit], axis=0), n[hit]) < 0
        inside[hit[back]] = True
        front = hit[~back]
        if len(front):
            q = p[ask[front]] - n[front] * hits.t[front, None]
            inside[front] = self._touch(q, hits.triangle[front])
        touching = touching.copy()
        touching[ask[~inside]] = False
        return touching


def _forget(verdicts: dict, lock: threading.RLock, key: int, _gone: weakref.ref) -> None:
    """Forget the sheet verdicts of samples that no longer exist (their id may come back for others)."""
    with lock:
        verdicts.pop(key, None)


def touching_planes(positions: np.ndarray, normals: np.ndarray, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """(sign (T,) int8 +1 / -1, candidate (T,) bool): each triangle's orientation against a fixed
    direction, and whether some triangle of the other orientation lies in its plane (unit normals on a
    NORMAL_STEP grid, offsets within about ``tolerance``)."""
    T = len(positions)
    sign = np.where(normals @ _CANONICAL >= 0, 1, -1).astype(np.int8)
    valid = np.einsum("ij,ij->i", normals, normals) > 0.5  # degenerate triangles have no plane
    if T == 0:
        return sign, np.zeros(0, bool)
    canonical = normals * sign[:, None]
    offset = np.einsum("ij,ij->i", canonical, positions.mean(axis=1))
    direction = np.round(canonical / NORMAL_STEP).astype(np.int64)
    candidate = np.zeros(T, bool)
    scale = max(float(tolerance), 1e-300)
    for shift in (0.0, 0.5):  # two grids of offsets: a pair astride one grid's step shares the other's
        keys = np.column_stack([direction, np.floor(offset / scale + shift).astype(np.int64)])
        candidate |= _both_signs(keys[valid], sign[valid], valid)
    return sign, candidate


def _both_signs(keys: np.ndarray, sign: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """(T,) bool over all triangles: the ``valid`` ones whose key row another of the other sign shares.

    Rows are hashed to one integer (a 1-D sort is ~20x faster than ``np.unique(axis=0)``): a collision
    only asks a few more samples, whose ray finds no touching face."""
    out = np.zeros(len(valid), bool)
    if len(keys) == 0:
        return out
    hashed = np.zeros(len(keys), np.uint64)
    with np.errstate(over="ignore"):
        for column in keys.T:
            hashed = hashed * np.uint64(0x9E3779B97F4A7C15) + column.astype(np.uint64)
    _, group = np.unique(hashed, return_inverse=True)
    group = group.ravel()
    plus = np.bincount(group, weights=(sign > 0).astype(np.float64))
    minus = np.bincount(group, weights=(sign < 0).astype(np.float64))
    out[np.flatnonzero(valid)] = (plus[group] > 0) & (minus[group] > 0)
    return out

