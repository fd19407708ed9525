"""Compiled kernels of Equation 3 (with its records' wall sectors), the albedo at hits, pass 3's gathering
rays and hits, its records' E_k and gradients from their cells, point lights' shadow rays, soft lamps' samples,
the lookups' Morton order, the bake's cosine-weighted ray directions and Algorithm 1's sums, with the numpy code
they replace as the fallback.

Equation 3 is looked up at every texel sample, at every gathering ray's hit and at every hit-grid cell,
and its numpy form spends most of its time making arrays per (point, record) pair; the albedo is read at
every photon and gathering hit; pass 3 casts ~100 M gathering rays, each set up, tallied and its hit
classified, and shadow rays to point lights leave every gap walk's vertex. The loops in
``core/native/pdic_native.c`` do the same floating-point operations in the same order as the numpy
functions they stand for (named in their docstrings below), so a bake gives the same light maps to the bit
either way (tests/test_native_kernels.py; ``tools/golden.py``). The wall sectors' test is the one
exception: it answers yes or no from an angle whose last bit numpy's SIMD arctan2 may round otherwise
(:func:`pair_walls`), which only a point within a rounding of a sector's edge could tell.

The library is our own C, built per platform by ``tools/build_native.py`` (the host's C compiler for a
checkout, zig for the extension's three platforms). It is optional: when the platform's library is
missing, of another version, or fails its check at load (a tiny problem compared with the numpy
functions, bit for bit), the numpy functions run instead and :func:`status` says why.
``PDIC_NATIVE=0`` in the environment turns the library off.
"""
from __future__ import annotations

import copy
import ctypes
import os
import platform
import threading
from pathlib import Path

import numpy as np

VERSION = 14
"""The C library's ``pdic_native_version()`` this module calls; a library of another version is not used."""
NATIVE_DIR = Path(__file__).resolve().parent / "native"
SUFFIX = {"linux": ".so", "windows": ".dll", "macos": ".dylib"}


def platform_name(system: str | None = None, machine: str | None = None) -> str:
    """Blender's platform name (``linux-x64``, ``windows-x64``, ``macos-arm64``, ...) of this machine."""
    system = (system or platform.system()).lower()
    machine = (machine or platform.machine()).lower()
    os_name = {"darwin": "macos", "win32": "windows"}.get(system, system)
    arch = {"x86_64": "x64", "amd64": "x64", "aarch64": "arm64", "arm64": "arm64"}.get(machine, machine)
    return f"{os_name}-{arch}"


def library_path(name: str | None = None) -> Path:
    """Where the library for platform ``name`` (default: this machine's) lives."""
    name = name or platform_name()
    return NATIVE_DIR / f"pdic_native-{name}{SUFFIX.get(name.split('-')[0], '.so')}"


_I64 = ctypes.c_int64
_F64 = ctypes.c_double
_PTR = ctypes.c_void_p

_lock = threading.RLock()
_lib = None
_status = None
_loading = False


def _ptr(a: np.ndarray | None):
    return None if a is None else a.ctypes.data_as(_PTR)


def _declare(lib) -> None:
    """The kernels' C signatures."""
    lib.pdic_zone_pairs.restype = _I64
    lib.pdic_zone_pairs.argtypes = [_PTR, _I64, _PTR, _F64, _PTR, _PTR, _PTR, _PTR, _PTR, _I64, _PTR, _PTR,
                                    _PTR, _PTR, _PTR, _I64]
    lib.pdic_ward_accept.restype = None
    lib.pdic_ward_accept.argtypes = [_PTR, _PTR, _PTR, _PTR, _PTR, _F64, _F64, _F64, _F64, _PTR, _PTR, _I64,
                                     _PTR, _PTR, _PTR]
    lib.pdic_equation3_sums.restype = None
    lib.pdic_equation3_sums.argtypes = [_PTR, _PTR, _PTR, _PTR, _PTR, _PTR, _PTR, _PTR, _I64, _PTR, _PTR, _PTR,
                                        _PTR, _I64, _PTR, _PTR, _PTR]
    lib.pdic_bilinear_rgb.restype = None
    lib.pdic_bilinear_rgb.argtypes = [_PTR, _I64, _I64, _PTR, _I64, _PTR]
    lib.pdic_albedo.restype = None
    lib.pdic_albedo.argtypes = [_PTR] * 10 + [_I64, _PTR]
    lib.pdic_cell_phi.restype = None
    lib.pdic_cell_phi.argtypes = [_PTR, _I64, _I64, _I64, _PTR, _PTR]
    lib.pdic_gathering_rays.restype = None
    lib.pdic_gathering_rays.argtypes = [_PTR, _I64, _I64, _I64, _I64] + [_PTR] * 7 + [_F64, _PTR, _PTR, _PTR]
    lib.pdic_tally_real_rays.restype = _I64
    lib.pdic_tally_real_rays.argtypes = [_PTR, _I64, _I64] + [_PTR] * 12
    lib.pdic_point_light_rays.restype = _I64
    lib.pdic_point_light_rays.argtypes = [_PTR, _PTR, _PTR, _I64, _PTR, _F64] + [_PTR] * 6
    lib.pdic_morton_keys.restype = None
    lib.pdic_morton_keys.argtypes = [_PTR, _I64, _PTR]
    lib.pdic_morton_order.restype = None
    lib.pdic_morton_order.argtypes = [_PTR, _I64] + [_PTR] * 4
    lib.pdic_pair_walls.restype = None
    lib.pdic_pair_walls.argtypes = [_PTR, _PTR, _I64] + [_PTR] * 4 + [_I64] + [_PTR] * 3 + [_F64] * 4 + [_PTR] * 2
    lib.pdic_cell_gradients.restype = _I64
    lib.pdic_cell_gradients.argtypes = [_PTR] * 4 + [_I64] * 4 + [_F64] * 2 + [_PTR] * 7
    lib.pdic_add_rows3.restype = None
    lib.pdic_add_rows3.argtypes = [_PTR, _I64, _PTR, _PTR, _I64, _PTR]
    lib.pdic_hit_cells.restype = None
    lib.pdic_hit_cells.argtypes = ([_PTR] * 5 + [_I64] + [_PTR] * 3 + [_I64] + [_PTR] * 2 + [_I64] * 2
                                   + [_F64, _PTR] + [_F64] * 4 + [_PTR] * 7)
    lib.pdic_disk_samples.restype = None
    lib.pdic_disk_samples.argtypes = [_PTR] * 5 + [_I64] * 2 + [_PTR] * 2
    lib.pdic_shadow_segments.restype = None
    lib.pdic_shadow_segments.argtypes = [_PTR] * 3 + [_I64, _F64] + [_PTR] * 4
    lib.pdic_area_facing.restype = None
    lib.pdic_area_facing.argtypes = [_PTR] * 3 + [_I64] + [_PTR] * 4
    lib.pdic_area_samples.restype = None
    lib.pdic_area_samples.argtypes = [_PTR] * 4 + [_I64] * 2 + [_PTR] * 4 + [_F64] * 2 + [_PTR] * 3
    lib.pdic_cell_bytes.restype = _I64
    lib.pdic_cell_bytes.argtypes = []
    lib.pdic_concentric_polar.restype = None
    lib.pdic_concentric_polar.argtypes = [_PTR, _I64, _PTR, _PTR]
    lib.pdic_cosine_directions.restype = None
    lib.pdic_cosine_directions.argtypes = [_PTR] * 4 + [_I64, _PTR]
    lib.pdic_pattern_directions.restype = None
    lib.pdic_pattern_directions.argtypes = [_PTR, _I64, _PTR, _I64, _PTR]
    lib.pdic_add_hard_light.restype = None
    lib.pdic_add_hard_light.argtypes = [_PTR] * 4 + [_I64] + [_PTR] * 3
    lib.pdic_accumulate.restype = None
    lib.pdic_accumulate.argtypes = [_PTR, _I64] + [_PTR] * 4 + [_I64] + [_PTR] * 4


def _load():
    path = library_path()
    if os.environ.get("PDIC_NATIVE", "1") == "0":
        return None, "off (PDIC_NATIVE=0)"
    if not path.is_file():
        return None, f"numpy (no compiled kernels for {platform_name()}: {path.name} not found)"
    try:
        lib = ctypes.CDLL(str(path))
    except OSError as exc:
        return None, f"numpy ({path.name} did not load: {exc})"
    try:
        lib.pdic_native_version.restype = _I64
        if lib.pdic_native_version() != VERSION:
            return None, f"numpy ({path.name} is version {lib.pdic_native_version()}, this code needs {VERSION})"
        _declare(lib)
        problem = _self_check(lib)
    except Exception as exc:  # a library this code cannot call must not stop a bake: numpy runs instead
        problem = f"{type(exc).__name__}: {exc}"
    if problem:
        return None, f"numpy ({path.name} failed its check: {problem})"
    return lib, f"compiled ({path.name})"


def library():
    """The loaded library, or None (then :func:`status` says why); loaded and checked once. While the check
    runs, the numpy code it compares with gets None here (the lock is the loading thread's own)."""
    global _lib, _status, _loading
    if _status is None:
        with _lock:
            if _loading:
                return None
            if _status is None:
                _loading = True
                try:
                    _lib, _status = _load()
                finally:
                    _loading = False
    return _lib


def status() -> str:
    """How Equation 3 runs here: ``compiled (<file>)`` or why it is numpy (for the manifest and the log)."""
    library()
    return _status


def _f64(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64)


def _vec3(v) -> np.ndarray:
    """One 3-vector (a light's centre, normal or axis) as the kernels read it."""
    return _f64(np.broadcast_to(np.asarray(v, np.float64), (3,)))


def _i64(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.int64)


def _writable(a: np.ndarray) -> bool:
    """Whether a kernel may write into ``a`` in place: C-contiguous and writable (numpy itself refuses to write a
    read-only array; C would not)."""
    return a.flags.c_contiguous and a.flags.writeable


def _within(index: np.ndarray, n: int) -> bool:
    """Whether every entry of ``index`` lies in [0, n): a kernel writing at them must not write past its array."""
    return len(index) == 0 or (0 <= int(index.min()) and int(index.max()) < n)


def zone_pairs(lib, grid, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`core.zone_grid.ZoneGrid.pairs` in C (the grid's own arrays, the same pairs in the same order)."""
    q = _f64(q)
    dense = grid.cells is None
    tables = [_i64(grid.first), None, None, None] if dense else [None, *map(_i64, (grid.cells, grid.start, grid.stop))]
    table = (*map(_ptr, tables), 0 if dense else len(grid.cells))  # tables holds the arrays during the call
    keep = [_f64(grid.origin), _i64(grid.dims), _f64(grid.entry_p), _f64(grid.entry_zone2), _i64(grid.records)]
    args = (_ptr(q), len(q), _ptr(keep[0]), float(grid.cell), _ptr(keep[1]), *table, *map(_ptr, keep[2:]))
    capacity = 4 * len(q) + 64
    while True:
        rows, records = np.empty(capacity, np.int64), np.empty(capacity, np.int64)
        count = lib.pdic_zone_pairs(*args, _ptr(rows), _ptr(records), capacity)
        if count <= capacity:
            return rows[:count], records[:count]
        capacity = count


def ward_accept(lib, p, n, p_k, n_k, R, R_add: float, a: float, rows, rec):
    """:func:`core.ward.ward_weight`, :func:`core.ward.accepted` and the squared distance over the pairs
    (rows, rec) of points p, n against records p_k, n_k, R (+ R_add): (w, ok, d2), each (pairs,)."""
    from .ward import DENOMINATOR_FLOOR, IN_FRONT  # here: tools/build_native.py loads this file on its own

    P = len(rows)
    w, ok, d2 = np.empty(P), np.empty(P, np.uint8), np.empty(P)
    arrays = [_f64(p), _f64(n), _f64(p_k), _f64(n_k), _f64(R), _i64(rows), _i64(rec)]
    lib.pdic_ward_accept(*map(_ptr, arrays[:5]), float(R_add), 1.0 / a, DENOMINATOR_FLOOR, IN_FRONT,
                         _ptr(arrays[5]), _ptr(arrays[6]), P, _ptr(w), _ptr(ok), _ptr(d2))
    return w, ok.view(bool), d2


def equation3_sums(lib, m: int, p, n, at, p_k, n_k, E_k, grad_r, grad_t, zone, rows, rec, w):
    """The sums of Equation 3 over accepted pairs, as :func:`core.interpolation.equation3_sums`:
    (num (m, c), den (m,), smallest (m,) or None without ``zone``)."""
    channels = E_k.shape[1]
    num, den = np.zeros((m, channels)), np.zeros(m)
    smallest = None if zone is None else np.full(m, np.inf)
    arrays = [_f64(p), _f64(n), None if at is None else _f64(at), _f64(p_k), _f64(n_k), _f64(E_k),
              None if grad_r is None else _f64(grad_r), None if grad_t is None else _f64(grad_t)]
    zone = None if zone is None else _f64(zone)
    rows, rec, w = _i64(rows), _i64(rec), _f64(w)
    lib.pdic_equation3_sums(*map(_ptr, arrays), channels, _ptr(zone), _ptr(rows), _ptr(rec), _ptr(w), len(rows),
                            _ptr(num), _ptr(den), _ptr(smallest))
    return num, den, smallest


def bilinear_rgb(lib, pixels: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """:func:`core.albedo.sample_texture`'s bilinear blend in C over (H, W, 3) float32 pixels at finite uv
    (n, 2): (n, 3) float32, the same values."""
    px, uv = np.ascontiguousarray(pixels, np.float32), _f64(uv)
    out = np.empty((len(uv), 3), np.float32)
    lib.pdic_bilinear_rgb(_ptr(px), px.shape[0], px.shape[1], _ptr(uv), len(uv), _ptr(out))
    return out


def albedo(lib, scene, triangles: np.ndarray, barycentric: np.ndarray) -> np.ndarray:
    """:func:`core.albedo.albedo` in C for triangle indices already checked: (h, 3) float32, the same values."""
    g, mats, textures = scene.geometry, scene.materials, scene.textures
    pixels = [np.ascontiguousarray(t.pixels, np.float32) for t in textures]
    table = (ctypes.c_void_p * max(len(pixels), 1))(*[p.ctypes.data for p in pixels])
    arrays = [np.ascontiguousarray(g.material, np.int32), np.ascontiguousarray(mats.base_color, np.float32),
              np.ascontiguousarray(mats.texture, np.int32), np.ascontiguousarray(g.uvs, np.float32), None,
              np.array([p.shape[0] for p in pixels] or [1], np.int64),
              np.array([p.shape[1] for p in pixels] or [1], np.int64),
              np.array([t.interpolation == "Linear" for t in textures] or [1], np.uint8),
              _i64(triangles), _f64(barycentric)]
    out = np.empty((len(triangles), 3), np.float32)
    ptrs = [_ptr(a) for a in arrays]
    ptrs[4] = ctypes.cast(table, _PTR)
    lib.pdic_albedo(*ptrs, len(triangles), _ptr(out))
    return out


def gathering_rays(lib, hemisphere, cells: np.ndarray, u: np.ndarray, frames, epsilon: float):
    """:func:`core.real_rays.gathering_rays` in C, phi's cosine and sine by numpy: (w_local, d_world, origin),
    each (n, 3), the same values."""
    cells, u = _i64(cells), _f64(u)
    n, C, N = len(cells), hemisphere.cells, hemisphere.columns
    phi = np.empty(n)
    lib.pdic_cell_phi(_ptr(cells), n, C, N, _ptr(u), _ptr(phi))
    cos_phi, sin_phi = np.cos(phi), np.sin(phi)
    p_k, t1, t2, normal = (_f64(v) for v in frames)
    w, d, o = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
    lib.pdic_gathering_rays(_ptr(cells), n, C, N, hemisphere.rows, _ptr(u), _ptr(cos_phi), _ptr(sin_phi),
                            _ptr(p_k), _ptr(t1), _ptr(t2), _ptr(normal), float(epsilon), _ptr(w), _ptr(d), _ptr(o))
    return w, d, o


def cosine_directions(lib, u: np.ndarray, n: np.ndarray) -> np.ndarray:
    """:func:`core.sampling.cosine_directions` in C, the disk angle's cosine and sine by numpy: (m, 3), the same
    values."""
    u, n = _f64(u), _f64(n)
    m = len(u)
    r, phi, d = np.empty(m), np.empty(m), np.empty((m, 3))
    lib.pdic_concentric_polar(_ptr(u), m, _ptr(r), _ptr(phi))
    lib.pdic_cosine_directions(_ptr(r), _ptr(np.cos(phi)), _ptr(np.sin(phi)), _ptr(n), m, _ptr(d))
    return d


def pattern_directions(lib, w_local: np.ndarray, n: np.ndarray) -> np.ndarray:
    """:func:`core.sampling.pattern_directions` in C: (m, r, 3), the same values."""
    w_local, n = _f64(w_local), _f64(n)
    d = np.empty((len(n), len(w_local), 3))
    lib.pdic_pattern_directions(_ptr(w_local), len(w_local), _ptr(n), len(n), _ptr(d))
    return d


def accumulate(lib, w_sum: np.ndarray, E_sum: np.ndarray, members: np.ndarray, w: np.ndarray, E_k: np.ndarray,
               slot_of: np.ndarray) -> bool:
    """:func:`core.irradiance_cache._accumulate_numpy` in C, in place, the same sums; False (nothing done) where
    w_sum (c,) and E_sum (c, 3) are not both writable C-contiguous float32 or both float64. slot_of : (c,) int64
    all -1, scratch the kernel leaves all -1."""
    single = w_sum.dtype == np.float32
    if not (w_sum.dtype == E_sum.dtype and w_sum.dtype in (np.float32, np.float64) and _writable(w_sum)
            and _writable(E_sum) and E_sum.shape == (len(w_sum), 3)):
        return False
    if not (slot_of.dtype == np.int64 and slot_of.flags.c_contiguous and len(slot_of) == len(w_sum)):
        raise ValueError("slot_of must be C-contiguous int64, one per candidate")
    members, w, E_k = _i64(members), _f64(w), _f64(E_k)
    m = len(members)
    if not _within(members, len(w_sum)):
        raise ValueError("accumulate: a candidate outside the sums")
    lib.pdic_accumulate(_ptr(members), m, _ptr(w), _ptr(E_k), _ptr(w_sum), _ptr(E_sum), int(single), _ptr(slot_of),
                        _ptr(np.empty(m, np.int64)), _ptr(np.empty(m)), _ptr(np.empty((m, 3))))
    return True


def tally_real_rays(lib, sums, cells: np.ndarray, w_local: np.ndarray, hits, origin: np.ndarray,
                    d_world: np.ndarray):
    """:func:`core.real_rays.tally_real_rays` in C: the same sums in ``sums`` and the same (hit, q, inv_sum,
    inv_n)."""
    for a in (sums.rot_sum, sums.count, sums.r_min):  # written in place
        if not (a.flags.c_contiguous and a.dtype == np.float64):
            raise ValueError("CellSums arrays must be C-contiguous float64")
    arrays = [_i64(cells), _f64(w_local), _f64(hits.t), _i64(hits.triangle), _f64(origin), _f64(d_world)]
    n = len(cells)
    inv_sum, inv_n = np.zeros(sums.B), np.zeros(sums.B)
    hit, q = np.empty(n, np.int64), np.empty((n, 3))
    h = lib.pdic_tally_real_rays(_ptr(arrays[0]), n, sums.H.cells, *map(_ptr, arrays[1:]), _ptr(sums.rot_sum),
                                 _ptr(sums.count), _ptr(sums.r_min), _ptr(inv_sum), _ptr(inv_n), _ptr(hit), _ptr(q))
    return hit[:h], q[:h], inv_sum, inv_n


def cell_gradients(lib, sums, r_floor: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:meth:`core.gather_cells.CellSums.irradiance_and_gradients`'s cells into E (B, c), grad_r, grad_t
    (B, c, 3) in the records' local frames, as :meth:`core.hemisphere.Hemisphere.irradiance_and_gradients`
    computes them from ``sums`` (a CellSums) with hit distances at least ``r_floor``."""
    H, B = sums.H, sums.B
    size, c = B * H.cells, sums.L_sum.shape[1]
    shapes = (sums.L_sum.shape, sums.rot_sum.shape, sums.count.shape, sums.r_min.shape)
    if c > 6 or shapes != ((size, c), (size, 3), (size,), (size,)):
        raise ValueError(f"cell_gradients: cell sums of shapes {shapes} for {B} records of {H.cells} cells")
    arrays = [_f64(a) for a in (sums.L_sum, sums.rot_sum, sums.count, sums.r_min, *H.gradient_coefficients())]
    E, grad_r, grad_t = np.empty((B, c)), np.empty((B, c, 3)), np.empty((B, c, 3))
    if lib.pdic_cell_gradients(*map(_ptr, arrays[:4]), B, H.rows, H.columns, c, float(r_floor), H.cell_weight,
                               *map(_ptr, arrays[4:]), _ptr(E), _ptr(grad_r), _ptr(grad_t)) != 0:
        raise MemoryError(f"cell_gradients: no scratch memory for {H.cells} cells")
    return E, grad_r, grad_t


def add_rows3(lib, table: np.ndarray, rows: np.ndarray, values: np.ndarray) -> None:
    """``table[rows, :3] += values`` in place, as numpy does it (a row given twice keeps its last sum): table
    (n, w >= 3) float64 C-contiguous, rows (h,) in [0, n), values (h, 3)."""
    rows, values = _i64(rows), _f64(values)
    if (table.dtype != np.float64 or table.ndim != 2 or table.shape[1] < 3 or not _writable(table)
            or values.shape != (len(rows), 3)):
        raise ValueError(f"add_rows3: a {table.dtype}{table.shape} table, {values.shape} values for {len(rows)} rows")
    if not _within(rows, len(table)):
        raise IndexError(f"add_rows3: rows outside the table's {len(table)}")
    lib.pdic_add_rows3(_ptr(table), table.shape[1], _ptr(rows), _ptr(values), len(rows), _ptr(np.empty_like(values)))


def point_light_rays(lib, p, n_s, n_g, c, epsilon: float) -> tuple:
    """:func:`core.lights.point_light_rays` in C: the same (rows, weight, start, directions, t_max, open)."""
    p, n_s, n_g, c = _f64(p), _f64(n_s), _f64(n_g), _f64(c)
    m = len(p)
    rows, weight, t_max, lit = np.empty(m, np.int64), np.empty(m), np.empty(m), np.empty(m, np.uint8)
    start, directions = np.empty((m, 3)), np.empty((m, 3))
    k = lib.pdic_point_light_rays(_ptr(p), _ptr(n_s), _ptr(n_g), m, _ptr(c), float(epsilon), _ptr(rows), _ptr(weight),
                                  _ptr(start), _ptr(directions), _ptr(t_max), _ptr(lit))
    return rows[:k], weight[:k], start[:k], directions[:k], t_max[:k], lit[:k].view(bool)


def add_hard_light(lib, E: np.ndarray, edge_lit: np.ndarray | None, edge_open: np.ndarray | None, rows: np.ndarray,
                   P: np.ndarray, weight: np.ndarray, vis: np.ndarray) -> None:
    """:func:`core.direct._add_hard_light_numpy` in C: the same sums in E (and edge_lit, edge_open), in place."""
    for a in (E, edge_lit, edge_open):
        if a is not None and not (a.dtype == np.float64 and _writable(a) and a.shape == E.shape and a.ndim == 2
                                  and a.shape[1] == 3):
            raise ValueError("add_hard_light: the sums must be writable C-contiguous float64 (n, 3)")
    if (edge_lit is None) != (edge_open is None):
        raise ValueError("add_hard_light: edge_lit and edge_open come together")
    rows, weight, vis = _i64(rows), _f64(weight), _f64(vis)
    k = len(rows)
    if len(weight) != k or len(vis) != k:
        raise ValueError("add_hard_light: rows, weights and transmittances disagree")
    if not _within(rows, len(E)):
        raise ValueError("add_hard_light: a row outside the sums")
    lib.pdic_add_hard_light(_ptr(E), _ptr(edge_lit), _ptr(edge_open), _ptr(rows), k, _ptr(_vec3(P)), _ptr(weight),
                            _ptr(vis))


def disk_samples(lib, q, pk, nsk, ngk, n_disk) -> tuple:
    """:func:`core.lights.disk_samples_numpy` in C without a spot mask: the same (weight (k, m), ok (k, m))."""
    q, pk, nsk, ngk, n_disk = _f64(q), _f64(pk), _f64(nsk), _f64(ngk), _f64(n_disk)
    k, m = q.shape[0], q.shape[1]
    if q.shape != (k, m, 3) or any(v.shape != (k, 3) for v in (pk, nsk, ngk, n_disk)):
        raise ValueError(f"disk_samples: samples {q.shape} and points {pk.shape}, {nsk.shape}, {ngk.shape}, "
                         f"{n_disk.shape} disagree")
    weight, ok = np.empty((k, m)), np.empty((k, m), np.uint8)
    lib.pdic_disk_samples(_ptr(q), _ptr(pk), _ptr(nsk), _ptr(ngk), _ptr(n_disk), k, m, _ptr(weight), _ptr(ok))
    return weight, ok.view(bool)


def shadow_segments(lib, points, normals, targets, epsilon: float) -> tuple:
    """:func:`core.rays.shadow_segments_numpy` in C for points with normals and targets without: the same (start,
    directions, t_max, open)."""
    points, normals = _f64(points), _f64(normals)
    targets = _f64(np.broadcast_to(np.asarray(targets, np.float64), points.shape))
    if points.ndim != 2 or points.shape[1] != 3 or normals.shape != points.shape:
        raise ValueError(f"shadow_segments: points {points.shape} and normals {normals.shape} disagree")
    m = len(points)
    start, directions, t_max, open_ = np.empty((m, 3)), np.empty((m, 3)), np.empty(m), np.empty(m, np.uint8)
    lib.pdic_shadow_segments(_ptr(points), _ptr(normals), _ptr(targets), m, float(epsilon), _ptr(start),
                             _ptr(directions), _ptr(t_max), _ptr(open_))
    return start, directions, t_max, open_.view(bool)


def area_facing(lib, p, n_s, n_g, c, N, corners) -> np.ndarray:
    """:func:`core.lights.area_facing_numpy` in C: the same (n,) bool."""
    p, n_s, n_g, corners = _f64(p), _f64(n_s), _f64(n_g), _f64(corners)
    c, N = _vec3(c), _vec3(N)
    if n_s.shape != p.shape or n_g.shape != p.shape or corners.shape != (4, 3):
        raise ValueError(f"area_facing: points {p.shape}, normals {n_s.shape}, {n_g.shape}, corners {corners.shape}")
    facing = np.empty(len(p), np.uint8)
    lib.pdic_area_facing(_ptr(p), _ptr(n_s), _ptr(n_g), len(p), _ptr(c), _ptr(N), _ptr(corners), _ptr(facing))
    return facing.view(bool)


def area_samples(lib, xy, pk, nsk, ngk, c, N, U, V, pdf_area: float, lift: float) -> tuple:
    """:func:`core.lights.area_samples_numpy` in C: the same (targets (k, m, 3), weight (k, m), ok (k, m))."""
    xy, pk, nsk, ngk = _f64(xy), _f64(pk), _f64(nsk), _f64(ngk)
    c, N, U, V = _vec3(c), _vec3(N), _vec3(U), _vec3(V)
    k, m = xy.shape[0], xy.shape[1]
    if pk.shape != (k, 3) or nsk.shape != (k, 3) or ngk.shape != (k, 3) or xy.shape != (k, m, 2):
        raise ValueError(f"area_samples: xy {xy.shape} and points {pk.shape}, {nsk.shape}, {ngk.shape} disagree")
    targets, weight, ok = np.empty((k, m, 3)), np.empty((k, m)), np.empty((k, m), np.uint8)
    lib.pdic_area_samples(_ptr(xy), _ptr(pk), _ptr(nsk), _ptr(ngk), k, m, _ptr(c), _ptr(N), _ptr(U), _ptr(V),
                          float(pdf_area), float(lift), _ptr(targets), _ptr(weight), _ptr(ok))
    return targets, weight, ok.view(bool)


def hit_cells(lib, caster, grid, triangle, barycentric, q, direction, distance, gap_tests):
    """:func:`core.real_rays.hit_cells` in C over hit grid ``grid`` (``gap_tests``:
    :func:`core.real_rays.gap_tests`): the same (n_hit, E, centroid, rho, is_open, near, gap)."""
    from .constants import HIT_GRID_NEAR  # here: tools/build_native.py loads this file on its own
    from .hit_radiance import CELL

    h, V = len(triangle), grid.E.shape[1]
    cells = grid.cells
    wrong = [why for why, bad in (
        (f"of dtype {cells.dtype}, not core.hit_radiance.CELL", cells.dtype != CELL),
        ("not contiguous", not cells.flags.c_contiguous),
        ("not on an 8-byte boundary", cells.ctypes.data % 8 != 0),
        (f"{len(cells)} rows for {V} cells", len(cells) != V)) if bad]
    if wrong:
        raise ValueError("hit grid cells " + ", ".join(wrong))
    tables = [_f64(caster.face_normals), _i64(grid.side), _i64(grid.offset), np.ascontiguousarray(grid.E, np.float32),
              cells]
    hits = [_i64(triangle), _f64(barycentric), _f64(direction), _f64(q), _f64(distance)]
    n_record, gap_reach, gap_cos, corner_reach, corner_height = gap_tests or (None, 0.0, 0.0, 0.0, 0.0)
    n_record = None if n_record is None else _f64(n_record)
    E, centroid, n_hit = np.empty((h, 3)), np.empty((h, 3)), np.empty((h, 3))
    rho = None if grid.albedo is None else np.empty((h, 3))
    flags = np.empty((3, h), np.uint8)  # open, near, gap
    lib.pdic_hit_cells(*map(_ptr, hits), h, *map(_ptr, tables[:3]), V, *map(_ptr, tables[3:]),
                       int(grid.albedo is not None), int(grid.open is not None), HIT_GRID_NEAR, _ptr(n_record),
                       float(gap_reach), float(gap_cos), float(corner_reach), float(corner_height), _ptr(E),
                       _ptr(centroid), _ptr(rho), _ptr(n_hit), *(_ptr(row) for row in flags))
    is_open, near, gap = flags.view(bool)
    return n_hit, E, centroid, rho, is_open, near, gap


def pair_walls(lib, rows, records, p, p_k, n_k, wall, reach) -> tuple[np.ndarray, np.ndarray]:
    """:func:`core.record_walls.beyond_wall_and_reach` in C for the pairs (rows, records) (w,) of points p (m, 3)
    and records p_k, n_k (K, 3) with walls ``wall`` (K, S) float32 and ``reach`` (K,): the same (past the
    polygon through ``reach``, past the far polygon), each (w,) bool, without gathering the pairs' vectors."""
    from .constants import FAR_WALL, SECTOR_OFFSET, TINY_WALL, WALL_MARGIN, WALL_RAYS  # here: see hit_cells
    from .record_walls import sector_directions

    rows, records = _i64(rows), _i64(records)
    p, p_k, n_k, reach = _f64(p), _f64(p_k), _f64(n_k), _f64(reach)
    if wall.dtype != np.float32:  # as IrradianceCache keeps them: numpy would read other values
        raise ValueError(f"walls must be float32, got {wall.dtype}")
    wall = np.ascontiguousarray(wall)
    for a, name in ((p, "p"), (p_k, "p_k"), (n_k, "n_k")):
        if a.ndim != 2 or a.shape[1] != 3:
            raise ValueError(f"{name} must be (n, 3), got {a.shape}")
    if wall.shape != (len(p_k), WALL_RAYS) or len(reach) != len(p_k) or len(n_k) != len(p_k):
        raise ValueError("wall (K, WALL_RAYS), reach (K,) and n_k (K, 3) must match p_k's K records")
    if len(rows) != len(records):
        raise ValueError("rows and records must pair up")
    if len(rows) and not (0 <= rows.min() and rows.max() < len(p) and 0 <= records.min()
                          and records.max() < len(p_k)):
        raise ValueError("a pair indexes past the points or the records")
    w = len(rows)
    cos_a, sin_a = (np.ascontiguousarray(v, np.float64) for v in sector_directions())
    past = np.zeros((2, w), np.uint8)
    if w:
        lib.pdic_pair_walls(_ptr(rows), _ptr(records), w, _ptr(p), _ptr(p_k), _ptr(n_k), _ptr(wall), WALL_RAYS, _ptr(reach),
                            _ptr(cos_a), _ptr(sin_a), SECTOR_OFFSET, FAR_WALL, 1.0 - WALL_MARGIN, TINY_WALL,
                            _ptr(past[0]), _ptr(past[1]))
    return past[0].view(bool), past[1].view(bool)


MORTON_BITS = 10
"""Bits per axis of the compiled Morton keys (three radix passes of 10 bits): core.zone_grid uses them only
while its own MORTON_BITS is the same."""


def _points(p) -> np.ndarray:
    p = _f64(p)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must be (m, 3), got {p.shape}")
    return p


def morton_keys(lib, p: np.ndarray) -> np.ndarray:
    """:func:`core.zone_grid.morton_keys_numpy` in C: (m,) uint64, the same keys."""
    p = _points(p)
    keys = np.empty(len(p), np.uint64)
    lib.pdic_morton_keys(_ptr(p), len(p), _ptr(keys))
    return keys


def morton_order(lib, p: np.ndarray) -> np.ndarray:
    """:func:`core.zone_grid.spatial_order` in C: np.argsort of the Morton keys, kind="stable" (a radix sort of
    their 30 bits), the same permutation."""
    p = _points(p)
    m = len(p)
    order = np.empty(m, np.int64)
    lib.pdic_morton_order(_ptr(p), m, _ptr(np.empty(m, np.uint64)), _ptr(np.empty(m, np.uint64)), _ptr(order),
                          _ptr(np.empty(m, np.int64)))
    return order


def _self_check(lib) -> str | None:
    """Compare the library with the numpy functions on a small random problem, to the bit.

    A library built wrong for its platform (fused multiply-adds, another calling convention) must not
    change a bake: then the numpy code runs instead."""
    from .interpolation import equation3_sums as sums_numpy
    from .ward import accepted, ward_weight
    from .vectors import dots
    from .zone_grid import ZoneGrid

    rng = np.random.default_rng(7)
    K, m = 64, 200
    p_k = rng.uniform(-1, 1, (K, 3))
    n_k = rng.normal(size=(K, 3))
    n_k /= np.linalg.norm(n_k, axis=1, keepdims=True)
    R = rng.uniform(0.05, 0.4, K)
    q = rng.uniform(-1.2, 1.2, (m, 3))
    n = rng.normal(size=(m, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    for cell_per_zone in (1.0, 3.0):
        grid = ZoneGrid(p_k, R, cell_per_zone)
        for sparse in (False, True):
            if sparse and grid.cells is None:  # the sorted-table branch over the same cells
                grid = copy.copy(grid)
                key = np.flatnonzero(np.diff(grid.first))
                grid.cells, grid.start, grid.stop = key, grid.first[key], grid.first[key + 1]
            want = grid.pairs_numpy(q)
            got = zone_pairs(lib, grid, q)
            if not all(np.array_equal(x, y) for x, y in zip(want, got)):
                return "zone pairs differ"
    rows, rec = want
    w0 = ward_weight(q[rows], n[rows], p_k[rec], n_k[rec], R[rec] + 0.01)
    ok0 = accepted(w0, 1.5, q[rows], n[rows], p_k[rec], n_k[rec], R[rec] + 0.01)
    d = q[rows] - p_k[rec]
    w, ok, d2 = ward_accept(lib, q, n, p_k, n_k, R, 0.01, 1.5, rows, rec)
    if not (np.array_equal(w, w0) and np.array_equal(ok, ok0) and np.array_equal(d2, dots(d, d))):
        return "Ward weights differ"
    E_k = rng.uniform(0, 2, (K, 3))
    g_r, g_t = rng.normal(size=(K, 3, 3)), rng.normal(size=(K, 3, 3))
    at = q[rows] + rng.normal(scale=0.01, size=(len(rows), 3))
    for args in ((None, g_r, g_t, R), (at, g_r, g_t, None), (None, None, None, R)):
        want = sums_numpy(m, q, n, args[0], p_k, n_k, E_k, args[1], args[2], args[3], rows, rec, w0)
        got = equation3_sums(lib, m, q, n, args[0], p_k, n_k, E_k, args[1], args[2], args[3], rows, rec, w0)
        if not all((x is None and y is None) or np.array_equal(x, y) for x, y in zip(want, got)):
            return "Equation 3's sums differ"
    return _self_check_texture(lib, rng) or _self_check_gathering(lib, rng)


def _self_check_gathering(lib, rng) -> str | None:
    from . import real_rays
    from .gather_cells import CellSums
    from .hemisphere import Hemisphere
    from .rays import Hits

    H, B = Hemisphere(3, 5), 4
    cells = rng.permutation(B * H.cells)[:40]
    u = rng.random((40, 2))
    n_k = rng.normal(size=(B, 3))
    n_k /= np.linalg.norm(n_k, axis=1, keepdims=True)
    t1 = np.cross(n_k, rng.normal(size=(B, 3)))
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    frames = (rng.normal(size=(B, 3)), t1, np.cross(n_k, t1), n_k)
    want = real_rays.gathering_rays_numpy(H, cells, u, frames, 1e-4)
    got = gathering_rays(lib, H, cells, u, frames, 1e-4)
    if not all(np.array_equal(x, y) for x, y in zip(want, got)):
        return "gathering rays differ"
    if not _self_check_directions(lib, rng):
        return "cosine directions differ"
    if not _self_check_accumulate(lib, rng):
        return "Algorithm 1's sums differ"
    w, d, o = want
    t = np.where(rng.random(40) < 0.3, np.inf, rng.uniform(0.0, 2.0, 40))
    hits = Hits(t, np.where(np.isinf(t), -1, rng.integers(0, 9, 40)), rng.random((40, 2)))
    sums = [CellSums(B, H), CellSums(B, H)]
    seen = rng.uniform(0.0, 2.0, len(sums[0].r_min[::3]))  # cells an earlier ray reached
    for s in sums:
        s.r_min[::3] = seen
    want = real_rays.tally_real_rays_numpy(sums[0], cells, w, hits, o, d)
    got = tally_real_rays(lib, sums[1], cells, w, hits, o, d)
    same = all(np.array_equal(x, y) for x, y in zip(want, got))
    same &= all(np.array_equal(getattr(sums[0], f), getattr(sums[1], f)) for f in ("rot_sum", "count", "r_min"))
    if not same:
        return "gathering tallies differ"
    return _self_check_cells(lib, rng)


def _self_check_directions(lib, rng) -> bool:
    """Cosine-weighted directions, and a pattern's directions, about normals of every sign (z = 0, -0.0 and -1
    among them), at u on the disk's centre and its diagonals, to the bit."""
    from .sampling import cosine_directions_numpy, pattern_directions_numpy

    n = rng.normal(size=(64, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    n[:4] = [[0.0, 0.0, -1.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, -0.0]]
    u = rng.random((64, 2))
    u[:3] = [[0.5, 0.5], [0.25, 0.25], [0.0, 0.75]]
    pattern = cosine_directions_numpy(u[:5], np.tile([0.0, 0.0, 1.0], (5, 1)))
    return (_same_bits(cosine_directions_numpy(u, n), cosine_directions(lib, u, n))
            and _same_bits(pattern_directions_numpy(pattern, n), pattern_directions(lib, pattern, n)))


def _self_check_accumulate(lib, rng) -> bool:
    """Algorithm 1's sums over candidates met once, many times or not at all, into float32 and float64 sums."""
    from .irradiance_cache import _accumulate_numpy

    members = rng.integers(0, 40, 300)
    w, E_k = rng.random(300) * 10.0 ** rng.uniform(-8, 2, 300), rng.normal(size=(300, 3))
    for dtype in (np.float32, np.float64):
        sums = [(np.full(50, 0.5, dtype), np.full((50, 3), 0.25, dtype)) for _ in range(2)]
        _accumulate_numpy(*sums[0], members, w, E_k)
        if not accumulate(lib, *sums[1], members, w, E_k, np.full(50, -1, np.int64)):
            return False
        if not all(_same_bits(a.astype(np.float64), b.astype(np.float64)) for a, b in zip(*sums)):
            return False
    return True


def _self_check_cells(lib, rng) -> str | None:
    from .gather_cells import CellSums
    from .hemisphere import Hemisphere

    for rows, columns, sky in ((3, 5, False), (2, 4, True)):
        sums = _cell_sums(CellSums(3, Hemisphere(rows, columns), sky), rng)
        want, got = sums.local_gradients(1e-3), cell_gradients(lib, sums, 1e-3)
        if not all(_same_bits(x, y) for x, y in zip(want, got)):
            return "cell gradients differ"
        rows = rng.integers(0, sums.size, 50)  # some twice: the last sum stays, as numpy's
        values = rng.normal(size=(50, 3))
        want = sums.L_sum.copy()
        want[rows, :3] += values
        add_rows3(lib, sums.L_sum, rows, values)
        if not np.array_equal(want, sums.L_sum):
            return "cell radiance sums differ"
    return _self_check_lights(lib, rng)


def _same_bits(x: np.ndarray, y: np.ndarray) -> bool:
    """Equal float64 arrays to the bit, the sign of a zero included (np.array_equal takes -0.0 for 0.0); other
    arrays (the kernels' flags) equal."""
    if x.dtype != np.float64 or y.dtype != np.float64:
        return x.dtype == y.dtype and np.array_equal(x, y)
    return x.shape == y.shape and np.array_equal(np.ascontiguousarray(x).view(np.uint64),
                                                 np.ascontiguousarray(y).view(np.uint64))


def _cell_sums(sums, rng):
    """``sums`` (a CellSums) filled at random as gathering fills it: some cells empty, several rays in others,
    misses at infinity, radiances from 0 to 1e3, a few negative rotational axes."""
    scale = rng.choice([0.0, 1e-3, 1.0, 1e3], size=sums.L_sum.shape)
    sums.L_sum[:] = rng.random(sums.L_sum.shape) * scale
    sums.rot_sum[:] = rng.normal(size=sums.rot_sum.shape)
    sums.rot_sum[: sums.H.cells] = -0.0  # a record whose products are all -0.0: numpy's sums give +0.0
    sums.count[:] = rng.integers(0, 4, sums.size)
    sums.r_min[:] = np.where(rng.random(sums.size) < 0.2, np.inf, rng.uniform(0.0, 2.0, sums.size))
    return sums


def _self_check_lights(lib, rng) -> str | None:
    from .lights import point_light_rays_numpy

    p = rng.normal(size=(300, 3))
    n_s, n_g = (v / np.linalg.norm(v, axis=1, keepdims=True) for v in rng.normal(size=(2, 300, 3)))
    c = np.array([0.1, -0.2, 0.3])
    p[::50] = c  # a point at the light
    want = point_light_rays_numpy(p, n_s, n_g, c, 1e-3)
    if not all(np.array_equal(x, y) for x, y in zip(want, point_light_rays(lib, p, n_s, n_g, c, 1e-3))):
        return "point light rays differ"
    if not _self_check_hard_light(lib, rng):
        return "a point light's sums differ"
    return _self_check_soft_lamps(lib, rng) or _self_check_hits(lib, rng) or _self_check_morton(lib, rng)


def _self_check_hard_light(lib, rng) -> bool:
    """A point light's light added at some rows of E, with the edge evidence and without, to the bit."""
    from .direct import DirectResult, _add_hard_light_numpy

    rows = np.sort(rng.choice(40, 25, replace=False))
    P, weight, vis = rng.uniform(0, 1e3, 3), rng.random(25) * 1e-3, np.where(rng.random(25) < 0.3, 0.0, rng.random(25))
    for edges in (False, True):
        sums = [rng.random((40, 3)) for _ in range(3)]
        if not edges:
            sums[1:] = [None, None]
        want = DirectResult(*sums)
        got = DirectResult(*(None if a is None else a.copy() for a in sums))
        _add_hard_light_numpy(want, rows, P, weight, vis)
        add_hard_light(lib, got.E, got.edge_lit, got.edge_open, rows, P, weight, vis)
        if not all(a is None or _same_bits(a, b) for a, b in zip((want.E, want.edge_lit, want.edge_open),
                                                                 (got.E, got.edge_lit, got.edge_open))):
            return False
    return True


def _self_check_soft_lamps(lib, rng) -> str | None:
    """The soft lamps' kernels: an area light's facing points and samples, a soft-falloff lamp's samples, the
    shadow segments of them all (a receiver on the light, zero-length segments, normals square to a segment)."""
    from .lights import area_facing_numpy, area_samples_numpy, disk_samples_numpy
    from .rays import shadow_segments_numpy

    k, m = 200, 16
    pk = rng.normal(size=(k, 3))
    nsk, ngk = (v / np.linalg.norm(v, axis=1, keepdims=True) for v in rng.normal(size=(2, k, 3)))
    xy = rng.uniform(-0.5, 0.5, size=(k, m, 2))
    xy[0, 0] = 0.0  # a sample at the light's centre, which pk[0] is put on: d = 0
    c, N = np.array([0.2, 0.1, 1.5]), np.array([0.0, 0.0, -1.0])
    pk[0] = c
    want = area_samples_numpy(xy, pk, nsk, ngk, c, N, np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), 4.0, 2e-3)
    got = area_samples(lib, xy, pk, nsk, ngk, c, N, np.array([1.0, 0, 0]), np.array([0, 1.0, 0]), 4.0, 2e-3)
    if not all(_same_bits(x, y) for x, y in zip(want, got)):
        return "area light samples differ"
    corners = c + rng.uniform(-0.5, 0.5, size=(4, 3)) * [1.0, 1.0, 0.0]
    if not _same_bits(area_facing_numpy(pk, nsk, ngk, c, N, corners), area_facing(lib, pk, nsk, ngk, c, N, corners)):
        return "area light facing points differ"
    n_disk = -nsk[:, ::-1].copy()
    if not all(_same_bits(x, y) for x, y in zip(disk_samples_numpy(want[0], pk, nsk, ngk, n_disk),
                                               disk_samples(lib, want[0], pk, nsk, ngk, n_disk))):
        return "disk lamp samples differ"
    targets = want[0].reshape(-1, 3).copy()
    points, normals = np.repeat(pk, m, axis=0), np.repeat(nsk, m, axis=0)
    targets[::37] = points[::37]  # zero-length segments
    normals[::41] = np.cross(normals[::41], targets[::41] - points[::41])  # normals square to the segment
    if not all(_same_bits(x, y) for x, y in zip(shadow_segments_numpy(points, normals, targets, 1e-3),
                                               shadow_segments(lib, points, normals, targets, 1e-3))):
        return "shadow segments differ"
    return None


def _self_check_morton(lib, rng) -> str | None:
    from .zone_grid import MORTON_BITS as bits, morton_keys_numpy

    if bits != MORTON_BITS:  # core.zone_grid keeps numpy's keys then; the other kernels stay in use
        return None

    p = rng.normal(size=(500, 3)) * [1.0, 1e-3, 50.0]
    flat = p.copy()
    flat[:, 1] = 0.25  # a plane of points: one axis of zero extent
    nan_ = p.copy()
    nan_[7, 2] = np.nan
    inf_ = p.copy()
    inf_[3, 0] = np.inf
    for q in (p, flat, nan_, inf_, p[:1], np.zeros((0, 3))):
        if not np.array_equal(morton_keys(lib, q), morton_keys_numpy(q)):
            return "Morton keys differ"
        if not np.array_equal(morton_order(lib, q), np.argsort(morton_keys_numpy(q), kind="stable")):
            return "Morton order differs"
    return None


def _self_check_hits(lib, rng) -> str | None:
    from . import real_rays
    from .hit_radiance import CELL

    if lib.pdic_cell_bytes() != CELL.itemsize:  # the rows hit_cells passes are HitGrid's, whatever the build
        return f"hit-grid rows of {lib.pdic_cell_bytes()} bytes, not {CELL.itemsize}"
    caster, sources, hits = _grid_hits(rng, 30, 300)
    for n_record in (hits[-1], None):
        want = real_rays.hit_cells_numpy(caster, sources, *hits[:-1], n_record)
        got = hit_cells(lib, caster, sources.hit_grid, *hits[:-1], real_rays.gap_tests(sources, n_record))
        if not all((x is None and y is None) or np.array_equal(x, y) for x, y in zip(want, got)):
            return "hit cells differ"
    return _self_check_walls(lib, rng)


def _self_check_walls(lib, rng) -> str | None:
    from .record_walls import beyond_wall_and_reach

    rows, records, p, p_k, n_k, wall, reach = _wall_pairs(rng, 40, 30, 600)
    want = beyond_wall_and_reach(wall[records], p[rows] - p_k[records], n_k[records], reach[records])
    got = pair_walls(lib, rows, records, p, p_k, n_k, wall, reach)
    if not all(np.array_equal(a, b) for a, b in zip(want, got)):
        return "record walls differ"
    return None


def _wall_pairs(rng, m: int, K: int, w: int):
    """(rows, records, p, p_k, n_k, wall, reach): w random pairs of m points and K records whose sector walls
    are near, far, missing (inf) or all missing, normals of every sign (for the self-check and the tests)."""
    from .constants import WALL_RAYS

    n_k = rng.normal(size=(K, 3))
    n_k /= np.linalg.norm(n_k, axis=1, keepdims=True)
    n_k[0], n_k[1] = [0.0, 0.0, -1.0], [0.0, 0.0, 1.0]
    wall = rng.uniform(0.05, 1.0, (K, WALL_RAYS)).astype(np.float32)
    wall[rng.random((K, WALL_RAYS)) < 0.3] = np.inf
    wall[2] = np.inf
    return (rng.integers(0, m, w), rng.integers(0, K, w), rng.uniform(-1, 1, (m, 3)), rng.uniform(-1, 1, (K, 3)), n_k,
            wall, rng.uniform(0.1, 1.5, K))


def _grid_hits(rng, T: int, h: int, albedo: bool = True, open_cells: bool = True):
    """(caster, sources, (triangle, barycentric, q, direction, distance, n_record)): a random hit grid over T
    triangles and h gathering hits on it, gap tests on (for the self-check and the tests)."""
    from types import SimpleNamespace

    from .hit_radiance import HitGrid
    from .settings import Deviations

    side = rng.integers(1, 6, T)
    offset = np.concatenate([[0], np.cumsum(side * side)[:-1]])
    V = int((side * side).sum())
    E = rng.uniform(0.0, 5.0, (2, V, 3)).astype(np.float32)
    grid = HitGrid(side, offset, E, E, rng.normal(size=(V, 3)),
                   rng.random((V, 3), dtype=np.float32) if albedo else None, None,
                   rng.random((2, V)) < 0.5 if open_cells else None)
    normals = rng.normal(size=(T, 3))
    caster = SimpleNamespace(face_normals=normals / np.linalg.norm(normals, axis=1, keepdims=True))
    sources = SimpleNamespace(hit_grid=grid, gap_reach=0.3, deviations=Deviations())
    unit = rng.normal(size=(2, h, 3))
    unit /= np.linalg.norm(unit, axis=2, keepdims=True)
    bary = rng.uniform(-0.1, 1.1, (h, 2))
    bary[::7] = [0.5, 0.5 + 2 ** -40]  # past u + v = 1 by a rounding
    return caster, sources, (rng.integers(0, T, h), bary, rng.normal(size=(h, 3)), unit[0],
                             rng.uniform(0.0, 1.0, h), unit[1])


def _self_check_texture(lib, rng) -> str | None:
    from .albedo import bilinear_numpy

    pixels = rng.random((5, 7, 3), dtype=np.float32)
    uv = rng.uniform(-3, 3, (300, 2))
    if not np.array_equal(bilinear_numpy(pixels, uv), bilinear_rgb(lib, pixels, uv)):
        return "texture samples differ"
    from .albedo import albedo_numpy
    scene = _textured_scene(rng, 40)
    triangles = rng.integers(0, 40, 400)
    bary = rng.uniform(-0.2, 1.2, (400, 2))
    if not np.array_equal(albedo_numpy(scene, triangles, bary), albedo(lib, scene, triangles, bary)):
        return "albedos differ"
    return None


def _textured_scene(rng, T: int):
    """T random triangles with three materials: a constant colour, a bilinear and a closest-texel texture of
    a few pixels, some brighter than 1 (for the self-check and the tests)."""
    from .scene import Geometry, Materials, Scene, Texture

    tris = rng.normal(size=(T, 3, 3))
    normal = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    normals = np.repeat((normal / np.linalg.norm(normal, axis=1, keepdims=True))[:, None], 3, axis=1)
    geometry = Geometry(tris, normals.astype(np.float32),
                        rng.uniform(-3, 3, (T, 3, 2)).astype(np.float32), rng.integers(0, 3, T).astype(np.int32),
                        np.full(T, -1, np.int32))
    materials = Materials(["plain", "linear", "closest"], rng.random((3, 3)).astype(np.float32),
                          np.array([-1, 0, 1], np.int32), np.zeros((3, 3), np.float32))
    textures = [Texture("linear", rng.uniform(0, 1.5, (5, 7, 3))),
                Texture("closest", rng.uniform(0, 1.5, (3, 4, 3)), "Closest")]
    return Scene(geometry, materials, tuple(textures))
