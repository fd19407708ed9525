"""Shared light-map atlases: the charts of many objects packed into a few square images.

Game engines and web pages want few textures: one light map per object costs a
draw-call state change and a texture each. This module packs the charts that
:func:`core.unwrap.unwrap` made for each object (charting is the slow, cached
step) into shared ``size x size`` atlases with xatlas (``use_input_mesh_uvs``:
charts are kept, only scaled, rotated and placed):

* one texel density for all objects (``texels_per_unit``; 0 = the largest that
  fits everything into one atlas), times each object's ``density_scale``;
* as few atlases as fit, each object entirely inside one atlas (its
  ``PDIC_Lightmap`` UVs address one image), charts ``padding`` texels apart;
* each object is baked as its own target over a *window*: the integer texel
  rectangle of the atlas that holds its charts, with UVs re-expressed in it.
  The window's texel grid is the atlas's, so its texels are the atlas's texels
  and :func:`composite` copies covered texels unchanged, then dilates the whole
  atlas once (gutters between objects' charts are filled like any other gutter).

UVs follow Blender: u right, v up, in [0, 1]; image row 0 is v = 0.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import xatlas

from .dilate import dilated_rgba
from .unwrap import CHILD_SECONDS_BASE, CHILD_SECONDS_PER_TRIANGLE, UnwrapError, ask_child
from .xatlas_charts import GOOD_FILL, MAX_PACK_ATTEMPTS, pack_options

WINDOW_MARGIN = 1
"""Texels around an object's charts inside its window: conservative rasterisation touches the
texels a chart's edge crosses, which lie within one texel of the chart's UV bounding box."""
PACK_ATTEMPTS = 2
"""Child processes tried before the packing is given up: xatlas's packing hung once (every
thread waiting on a futex) in one of thousands of runs; a fresh process packed the same input."""


# --------------------------------------------------------------------------- inputs and results
@dataclass(frozen=True)
class AtlasInput:
    """One object's charts, to be packed.

    name : object name (messages, manifest).
    positions : (V, 3) float64 vertex positions at world size (object scale applied), scene units.
    triangles : (t, 3) int64 vertex indices.
    uv_chart : (t, 3, 2) float32 per-corner UVs of the object's own unwrap (charts
        are read from UV connectivity; their packing there does not matter).
    density_scale : this object's texel density relative to the atlas's (typical 1;
        2 gives it twice the texels per unit length).
    """

    name: str
    positions: np.ndarray
    triangles: np.ndarray
    uv_chart: np.ndarray
    density_scale: float = 1.0

    def __post_init__(self):
        p = np.asarray(self.positions, np.float64)
        t = np.asarray(self.triangles, np.int64)
        uv = np.asarray(self.uv_chart, np.float32)
        if p.ndim != 2 or p.shape[1] != 3 or not np.isfinite(p).all():
            raise ValueError(f"atlas: object {self.name!r}: positions must be finite (V, 3), got {p.shape}")
        if t.ndim != 2 or t.shape[1] != 3 or (t.size and (t.min() < 0 or t.max() >= len(p))):
            raise ValueError(f"atlas: object {self.name!r}: triangles must be (t, 3) indices into {len(p)} vertices")
        if uv.shape != (len(t), 3, 2) or not np.isfinite(uv).all():
            raise ValueError(f"atlas: object {self.name!r}: uv_chart must be finite ({len(t)}, 3, 2), got {uv.shape}")
        if not (math.isfinite(self.density_scale) and self.density_scale > 0):
            raise ValueError(f"atlas: object {self.name!r}: density_scale {self.density_scale!r} must be > 0")
        object.__setattr__(self, "positions", p)
        object.__setattr__(self, "triangles", t)
        object.__setattr__(self, "uv_chart", uv)

    def corner_positions(self) -> np.ndarray:
        """(t*3, 3) float32 corner positions scaled by ``density_scale`` (xatlas sizes charts by area)."""
        return (self.positions[self.triangles].reshape(-1, 3) * self.density_scale).astype(np.float32)

    def area(self) -> float:
        """Surface area after ``density_scale``, scene units squared."""
        c = self.positions[self.triangles] * self.density_scale
        return float(0.5 * np.linalg.norm(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), axis=1).sum())

    def valid(self) -> np.ndarray:
        """(t,) bool triangles with 3-D area (xatlas leaves the others out of every chart)."""
        c = self.positions[self.triangles]
        return np.linalg.norm(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), axis=1) > 0


@dataclass(frozen=True)
class Placement:
    """Where one object sits.

    name : object name.
    atlas : index of its atlas.
    uv : (t, 3, 2) float32 per-corner UVs in [0, 1] of the whole atlas.
    window : (x0, y0, width, height) int texels: the atlas rectangle holding its
        charts (x0 from the left, y0 from the bottom row, v = 0).
    chart : (t,) int32 chart of each triangle, unique within its atlas (-1: no area).
    """

    name: str
    atlas: int
    uv: np.ndarray
    window: tuple
    chart: np.ndarray | None = None

    def window_uv(self, size: int, uv: np.ndarray | None = None) -> np.ndarray:
        """(..., 2) float32 UVs in [0, 1] of the window: ``(uv * size - origin) / window size``.

        uv : atlas UVs, (..., 2) in [0, 1] (default: :attr:`uv`); e.g. the UVs an
            extraction read back from the mesh, whose triangles may be ordered otherwise.
        """
        x0, y0, w, h = self.window
        uv = self.uv if uv is None else uv
        return ((np.asarray(uv, np.float64) * size - [x0, y0]) / [w, h]).astype(np.float32)


@dataclass(frozen=True)
class AtlasLayout:
    """A packing: ``atlas_count`` images of ``size x size`` texels and each object's place."""

    size: int
    padding: int
    texels_per_unit: float
    atlas_count: int
    placements: tuple

    def placement(self, name: str) -> Placement:
        for p in self.placements:
            if p.name == name:
                return p
        raise KeyError(f"atlas: no object {name!r} in the layout")

    def manifest(self) -> dict:
        """JSON-ready description: per atlas its index, size and the objects with their windows."""
        atlases = [{"index": i, "width": self.size, "height": self.size,
                    "objects": [{"name": p.name, "window": [int(v) for v in p.window]}
                                for p in self.placements if p.atlas == i]}
                   for i in range(self.atlas_count)]
        return {"size": int(self.size), "padding": int(self.padding),
                "texels_per_unit": float(self.texels_per_unit), "atlases": atlases}


# --------------------------------------------------------------------------- packing
def pack_atlases(inputs: list, size: int, padding: int, texels_per_unit: float = 0.0, *,
                 in_process: bool = False, cancelled=None) -> AtlasLayout:
    """Pack every object's charts into as few ``size x size`` atlases as fit.

    xatlas runs in a child process (as :func:`core.unwrap.unwrap`'s charting does): a crash or a
    hang there cannot take Blender down; a child with no answer within the unwrap's time limit
    for as many triangles is killed and the packing tried again (:data:`PACK_ATTEMPTS`).

    Parameters
    ----------
    inputs : list of :class:`AtlasInput`, names unique.
    size : atlas width and height in texels (typical 1024-4096).
    padding : texels between charts (typical 2, as for per-object light maps).
    texels_per_unit : texels per scene unit for ``density_scale`` 1 (typical 4-64
        for metre scenes); 0 chooses the largest density that fits one atlas.
    in_process : run xatlas in this process (no crash protection; the child itself, tools).
    cancelled : called while the child runs; returning True kills it and raises
        ``core.executor.Cancelled``.

    Returns
    -------
    AtlasLayout

    Raises
    ------
    ValueError : bad sizes, duplicate names, or an object that alone does not fit
        one atlas at the requested density (the message names it).
    UnwrapError : every child crashed or hung.
    """
    if not inputs:
        raise ValueError("atlas: nothing to pack (no objects)")
    names = [i.name for i in inputs]
    if len(set(names)) != len(names):
        raise ValueError(f"atlas: object names must be unique, got {sorted(n for n in names if names.count(n) > 1)}")
    if size < 8 or padding < 0 or 2 * padding >= size:
        raise ValueError(f"atlas: size {size} with padding {padding} leaves no room for charts")
    if not (math.isfinite(texels_per_unit) and texels_per_unit >= 0):
        raise ValueError(f"atlas: texels_per_unit {texels_per_unit!r} must be >= 0 (0 = fit one atlas)")
    if not in_process:
        return _pack_in_child(inputs, size, padding, texels_per_unit, cancelled)
    if texels_per_unit == 0:
        texels_per_unit = _fit_one_atlas(inputs, size, padding)
        groups = [list(range(len(inputs)))]
    else:
        groups = _group(inputs, size, padding, texels_per_unit)
    placements = [None] * len(inputs)
    for a, group in enumerate(groups):
        atlas = _pack([inputs[k] for k in group], padding, texels_per_unit)
        for j, k in enumerate(group):
            placements[k] = _placement(inputs[k], atlas, j, a, size)
    return AtlasLayout(int(size), int(padding), float(texels_per_unit), len(groups), tuple(placements))


def _pack_in_child(inputs: list, size: int, padding: int, texels_per_unit: float, cancelled) -> AtlasLayout:
    """:func:`pack_atlases` in a child process (``core/unwrap_worker.py``, task ``atlas``)."""
    request, arrays = pack_request(inputs, size, padding, texels_per_unit)
    limit = CHILD_SECONDS_BASE + CHILD_SECONDS_PER_TRIANGLE * sum(len(i.triangles) for i in inputs)
    failures = []
    for _ in range(PACK_ATTEMPTS):
        answer, out = ask_child(request, arrays, cancelled, limit, "pdic-atlas-")
        if answer is None:
            failures.append(out)
            continue
        if answer.get("error") == "ValueError":
            raise ValueError(answer["message"])
        if answer.get("error"):
            raise UnwrapError(f"atlas packing failed: {answer['error']}: {answer['message']}")
        return layout_from_answer(answer, out)
    raise UnwrapError(f"xatlas could not pack the charts of {len(inputs)} objects into {size}x{size} atlases "
                      f"({'; '.join(failures)}); bake the objects without an atlas, or with fewer objects per bake")


def pack_request(inputs: list, size: int, padding: int, texels_per_unit: float) -> tuple[dict, dict]:
    """The child's request (JSON-ready scalars) and arrays for packing ``inputs``."""
    request = dict(task="atlas", size=int(size), padding=int(padding), texels_per_unit=float(texels_per_unit),
                   names=[i.name for i in inputs], density_scales=[float(i.density_scale) for i in inputs])
    arrays = {}
    for k, i in enumerate(inputs):
        arrays[f"positions_{k}"], arrays[f"triangles_{k}"], arrays[f"uv_{k}"] = i.positions, i.triangles, i.uv_chart
    return request, arrays


def inputs_from_request(request: dict, arrays) -> list:
    """The :class:`AtlasInput` list :func:`pack_request` described (in the child)."""
    return [AtlasInput(name, arrays[f"positions_{k}"], arrays[f"triangles_{k}"], arrays[f"uv_{k}"], scale)
            for k, (name, scale) in enumerate(zip(request["names"], request["density_scales"]))]


def layout_answer(layout: AtlasLayout) -> tuple[dict, dict]:
    """A packing as the child's JSON status and arrays (UVs and charts per placement)."""
    status = dict(size=layout.size, padding=layout.padding, texels_per_unit=layout.texels_per_unit,
                  atlas_count=layout.atlas_count,
                  placements=[dict(name=p.name, atlas=int(p.atlas), window=[int(v) for v in p.window])
                              for p in layout.placements])
    arrays = {}
    for k, p in enumerate(layout.placements):
        arrays[f"uv_{k}"], arrays[f"chart_{k}"] = p.uv, p.chart
    return status, arrays


def layout_from_answer(status: dict, arrays) -> AtlasLayout:
    """The :class:`AtlasLayout` :func:`layout_answer` wrote (in the parent)."""
    placements = tuple(Placement(p["name"], int(p["atlas"]), arrays[f"uv_{k}"].astype(np.float32), tuple(p["window"]),
                                 arrays[f"chart_{k}"].astype(np.int32))
                       for k, p in enumerate(status["placements"]))
    return AtlasLayout(int(status["size"]), int(status["padding"]), float(status["texels_per_unit"]),
                       int(status["atlas_count"]), placements)


def _pack(inputs: list, padding: int, texels_per_unit: float) -> "xatlas.Atlas":
    """One xatlas atlas of any size holding all ``inputs``' charts at ``texels_per_unit``."""
    atlas = xatlas.Atlas()
    for inp in inputs:
        valid = np.flatnonzero(inp.valid())
        faces = (valid[:, None] * 3 + np.arange(3)).astype(np.uint32)
        atlas.add_mesh(inp.corner_positions(), faces, None, inp.uv_chart.reshape(-1, 2))
    options = xatlas.ChartOptions()
    options.use_input_mesh_uvs = True
    atlas.generate(options, pack_options(0, padding, texels_per_unit))  # resolution 0: one atlas
    return atlas


def _side(atlas) -> int:
    return max(atlas.width, atlas.height)


def _fit_one_atlas(inputs: list, size: int, padding: int) -> float:
    """The largest texels-per-unit tried whose single atlas fits ``size``, stopping at
    :data:`~core.xatlas_charts.GOOD_FILL` of the side (packing is not linear in the scale:
    padding and 4x4 block alignment are fixed, hence a search)."""
    area = sum(i.area() for i in inputs)
    tpu = 0.7 * size / math.sqrt(max(area, 1e-30))  # ~50 % fill to start
    fit, overflow = 0.0, math.inf  # bracket: largest density that fits, smallest that does not
    for _ in range(2 * MAX_PACK_ATTEMPTS):
        side = _side(_pack(inputs, padding, tpu))
        fill = side / size
        if fill <= 1.0:
            fit = max(fit, tpu)
        else:
            overflow = min(overflow, tpu)
        if fit and (GOOD_FILL <= fill <= 1.0 or overflow / fit < 1.01):
            return fit
        # rescale by the side's ratio until the bracket closes, then halve it geometrically
        tpu = math.sqrt(fit * overflow) if fit and overflow < math.inf else tpu / fill * (0.98 if fill > 1 else 1.0)
    if not fit:
        raise ValueError(f"atlas: could not fit {len(inputs)} objects into one {size}x{size} atlas "
                         f"with padding {padding}; raise the atlas size")
    return fit


def _group(inputs: list, size: int, padding: int, tpu: float) -> list:
    """Objects per atlas: all in one if they fit, else first-fit decreasing by texel area,
    each bin checked by packing it (an overflowing bin hands its smallest object on)."""
    everything = list(range(len(inputs)))
    if _side(_pack(inputs, padding, tpu)) <= size:
        return [everything]
    area = np.array([i.area() for i in inputs]) * tpu * tpu
    order = [int(k) for k in np.argsort(-area, kind="stable")]
    bins: list = []
    pending = order
    while pending:
        current, rest, budget = [], [], 0.6 * size * size  # xatlas fills ~60-80 % with many charts
        for k in pending:
            if not current or area[k] <= budget:
                current.append(k)
                budget -= area[k]
            else:
                rest.append(k)
        while _side(_pack([inputs[k] for k in current], padding, tpu)) > size:
            if len(current) == 1:
                inp = inputs[current[0]]
                raise ValueError(f"atlas: object {inp.name!r} alone needs more than {size}x{size} texels at "
                                 f"{tpu:g} texels per unit (x{inp.density_scale:g}); lower the texel density "
                                 f"or raise the atlas size")
            rest.insert(0, current.pop())  # the smallest goes to the next atlas
        bins.append(sorted(current))
        pending = sorted(rest, key=lambda k: -area[k])
    return bins


def _placement(inp: AtlasInput, atlas, mesh: int, atlas_index: int, size: int) -> Placement:
    """UVs of mesh ``mesh`` of a packed ``atlas`` in [0, 1] of the ``size`` square, and its window."""
    _, index, uv = atlas[mesh]
    uv_texel = uv.astype(np.float64) * [atlas.width, atlas.height]
    valid = np.flatnonzero(inp.valid())
    chart = np.full(len(inp.triangles), -1, np.int32)
    chart[valid] = atlas.get_mesh_vertex_assignment(mesh)[1].astype(np.int32)[index[:, 0].astype(np.int64)]
    corner = np.zeros((len(inp.triangles), 3, 2))
    corner[valid] = uv_texel[index.astype(np.int64)]  # xatlas keeps face order
    corner = _place_degenerate(corner, inp, valid)
    uv_atlas = np.clip(corner / size, 0.0, 1.0).astype(np.float32)
    used = uv_atlas[valid].reshape(-1, 2).astype(np.float64) * size
    lo = np.floor(used.min(axis=0)).astype(int) - WINDOW_MARGIN if len(used) else np.zeros(2, int)
    hi = np.ceil(used.max(axis=0)).astype(int) + WINDOW_MARGIN if len(used) else np.ones(2, int)
    lo, hi = np.clip(lo, 0, size - 1), np.clip(hi, 1, size)
    hi = np.maximum(hi, lo + 1)
    window = (int(lo[0]), int(lo[1]), int(hi[0] - lo[0]), int(hi[1] - lo[1]))
    return Placement(inp.name, atlas_index, uv_atlas, window, chart)


def _place_degenerate(corner: np.ndarray, inp: AtlasInput, valid: np.ndarray) -> np.ndarray:
    """Triangles without area get the packed UV of the same vertex elsewhere (else a valid
    corner's): they hold no surface, but their UVs must stay inside the object's charts."""
    if len(valid) == len(inp.triangles):
        return corner
    vertex_uv = np.full((len(inp.positions), 2), np.nan)
    vertex_uv[inp.triangles[valid][::-1].reshape(-1)] = corner[valid][::-1].reshape(-1, 2)
    invalid = np.setdiff1d(np.arange(len(inp.triangles)), valid)
    fill = corner[valid[0], 0] if len(valid) else np.zeros(2)
    found = vertex_uv[inp.triangles[invalid]]
    corner[invalid] = np.where(np.isnan(found), fill, found)
    return corner


# --------------------------------------------------------------------------- images
def composite(layout: AtlasLayout, lightmaps: dict, coverage: dict, dilation: int) -> tuple[list, int]:
    """Atlas images from per-object window bakes.

    Parameters
    ----------
    layout : the packing the windows come from.
    lightmaps : object name -> (h, w, 4) float32 window light map (RGB = E / pi).
    coverage : object name -> (h, w) bool texels the object's triangles cover (before dilation).
    dilation : rings to grow every chart into its gutter (typical padding + 2).

    Returns
    -------
    atlases : list of (size, size, 4) float32 RGBA; covered texels hold their object's
        window values bit for bit, alpha = 1 where covered or dilated.
    conflicts : texels covered by two objects (0 for a valid packing).
    """
    S = layout.size
    rgb = [np.zeros((S, S, 3), np.float32) for _ in range(layout.atlas_count)]
    covered = [np.zeros((S, S), bool) for _ in range(layout.atlas_count)]
    conflicts = 0
    for p in layout.placements:
        x0, y0, w, h = p.window
        image, mask = np.asarray(lightmaps[p.name]), np.asarray(coverage[p.name], bool)
        if image.shape[:2] != (h, w) or mask.shape != (h, w):
            raise ValueError(f"atlas: object {p.name!r}: light map {image.shape[:2]} / coverage {mask.shape} "
                             f"do not match its window {w}x{h}")
        view_rgb, view_cov = rgb[p.atlas][y0:y0 + h, x0:x0 + w], covered[p.atlas][y0:y0 + h, x0:x0 + w]
        conflicts += int((view_cov & mask).sum())
        view_rgb[mask] = image[..., :3][mask]
        view_cov |= mask
    out = []
    for image, mask in zip(rgb, covered):
        out.append(dilated_rgba(image, mask, dilation))
    return out, conflicts
