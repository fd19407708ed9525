"""Light-map UVs: choose a resolution, unwrap with xatlas, map UVs back to polygon corners.

Every baked object needs a second UV map whose charts do not overlap and sit
``padding`` texels apart, so each texel belongs to one piece of surface. The
xatlas passes (charting, polygon fix, packing, overlap repair) are in
:mod:`core.xatlas_charts`; this module validates the input, serves and stores
content-keyed cache files, and runs those passes in a child Python process
(:mod:`core.unwrap_worker`): xatlas 0.0.11 crashes (SIGSEGV) on some meshes,
e.g. an ico sphere with 7 subdivisions (jpcy/xatlas#146), and in Blender's
own process that would take unsaved work down with it. A crashed child is
retried with other chart options, then reported; the child is also what makes
an unwrap cancellable (it is killed). Every result, computed or cached, is
checked for overlapping UV triangles (:func:`core.uv_overlap.uv_overlaps`)
before it is returned.

UVs follow Blender: u to the right, v up, in [0, 1].
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np
import xatlas

from .cache_files import read_entry, write_entry
from .uv_overlap import uv_overlaps

# Bump when anything here changes the UVs produced for the same input (cache key).
ALGORITHM_VERSION = 4
# Chart-option variants tried in turn when the xatlas child process crashes
# (see core.xatlas_charts.chart_options).
CHART_VARIANTS = 2
CHILD_SECONDS_BASE = 60.0
CHILD_SECONDS_PER_TRIANGLE = 5e-3
"""A child with no answer after BASE + PER_TRIANGLE x triangles seconds is taken as hung and
killed (then retried with other chart options): xatlas's thread pool was seen deadlocked once
in thousands of small unwraps. Generous: a 65k-triangle grid took 288 s in the child on a
2-core machine at load 17 (limit 385 s); 252k triangles get 22 minutes."""
EXIT_GRACE_SECONDS = 10.0
"""How long the child may take to exit after writing its answer before it is killed."""
# How often a waiting unwrap asks ``cancelled()`` (seconds).
POLL_SECONDS = 0.05


class UnwrapError(RuntimeError):
    """The unwrap could not produce a valid light-map layout; the message says why."""


class UnwrapCrashed(UnwrapError):
    """xatlas crashed (the child process died) with every chart-option variant."""


class PackError(UnwrapError):
    """The charts do not fit the largest allowed map. ``minimum``: a size seen to hold them, or 0."""

    def __init__(self, message: str, minimum: int = 0):
        super().__init__(message)
        self.minimum = minimum


class DegenerateMeshError(ValueError):
    """No triangle has an area (e.g. an object scaled to 0): nothing can be unwrapped."""


# --------------------------------------------------------------------------- resolution
def choose_resolution(surface_area: float, texel_density: float, default_resolution: int,
                      min_resolution: int, max_resolution: int) -> int:
    """Light-map width (= height) in texels for an object.

    Parameters
    ----------
    surface_area : total surface area of the object, scene units squared.
    texel_density : texels per scene unit; 0 means "use ``default_resolution``".
        Typical 8-64 for metre-scale scenes.
    default_resolution : resolution when ``texel_density`` is 0 (typical 256).
    min_resolution, max_resolution : clamp of the density-derived resolution.

    Returns
    -------
    int : ``default_resolution`` if the density is 0, else
        ``ceil(sqrt(surface_area) * texel_density)`` rounded up to a multiple of 4
        (block-compressed texture formats store 4x4 blocks) and clamped to [min, max].
    """
    if not (math.isfinite(surface_area) and math.isfinite(texel_density)):
        raise ValueError(f"choose_resolution: non-finite surface area {surface_area!r} or texel density {texel_density!r}")
    if texel_density < 0 or surface_area < 0:
        raise ValueError(f"choose_resolution: negative surface area {surface_area!r} or texel density {texel_density!r}")
    if min_resolution > max_resolution:
        raise ValueError(f"choose_resolution: min_resolution {min_resolution} > max_resolution {max_resolution}")
    if texel_density == 0:
        return int(default_resolution)
    texels = math.ceil(math.sqrt(surface_area) * texel_density)
    texels = 4 * math.ceil(texels / 4)
    return int(min(max(texels, min_resolution), max_resolution))


def uv_areas(uv: np.ndarray) -> np.ndarray:
    """(t,) area of each UV triangle of ``uv`` (t, 3, 2), in units of the whole map (float64)."""
    uv = np.asarray(uv, np.float64)
    e1, e2 = uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]
    return 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])


def achieved_texel_density(uv: np.ndarray, surface_area: float, resolution: int) -> float:
    """Texels per scene unit the unwrap gave, area-weighted over the mesh: sqrt(texels on triangles /
    surface area). Below the requested density when charts leave part of the map empty (padding,
    packing) or xatlas scales charts down to fit; 0 for a mesh without area.

    uv : (t, 3, 2) per-corner UVs in [0, 1]; surface_area : the mesh's area, scene units squared.
    """
    world = float(surface_area)
    uv_area = uv_areas(uv).sum()
    if not (world > 0 and np.isfinite(world) and np.isfinite(uv_area)):
        return 0.0
    return float(np.sqrt(uv_area * resolution * resolution / world))


# --------------------------------------------------------------------------- result
@dataclass(frozen=True)
class UnwrapResult:
    """Light-map UVs of one object.

    uv : (t, 3, 2) float32 per-triangle-corner UVs in [0, 1] (u right, v up),
        triangles in input order; corners with the same (polygon, vertex) have the
        same UV. A degenerate (zero-area) triangle, which xatlas leaves out of every
        chart, gets UVs inside its own polygon (zero UV area) or, if its polygon has
        no charted triangle, one point.
    chart_count : number of charts.
    utilization : fraction of the map covered by UV triangles (0..1, typical 0.3-0.8).
    from_cache : True if read from ``cache_dir`` instead of computed.
    polygons_fixed : polygons xatlas split across charts that were re-joined (0 when no
        polygon structure was given).
    chart : (t,) int32 chart of each triangle, -1 for degenerate triangles.
    resolution : side of the map the UVs are laid out for, texels; larger than the
        requested one when the charts did not fit it and growing was allowed.
    polygons_detached : polygons taken out of folded charts as islands of their own.
    overlaps : texel centres inside two or more UV triangles (always 0: checked).
    warnings : messages for the user (e.g. the cache folder could not be written).
    """

    uv: np.ndarray
    chart_count: int
    utilization: float
    from_cache: bool = False
    polygons_fixed: int = 0
    chart: np.ndarray | None = None
    resolution: int = 0
    polygons_detached: int = 0
    overlaps: int = 0
    warnings: tuple = ()


def cache_key(positions: np.ndarray, triangles: np.ndarray, resolution: int, padding: int,
              triangle_polygon: np.ndarray | None = None, max_resolution: int = 0,
              texels_per_unit: float = 0.0) -> str:
    """sha256 (hex) of everything the UVs depend on: geometry, polygons, resolution,
    padding, the growth limit, the texel density held, the xatlas version and
    :data:`ALGORITHM_VERSION`."""
    h = hashlib.sha256()
    h.update(b"pdic-unwrap\0")
    h.update(np.ascontiguousarray(positions, dtype=np.float64).tobytes())
    h.update(b"\0")
    h.update(np.ascontiguousarray(triangles, dtype=np.int64).tobytes())
    h.update(b"\0")
    if triangle_polygon is not None:
        h.update(np.ascontiguousarray(triangle_polygon, dtype=np.int64).tobytes())
    h.update(f"\0{int(resolution)}\0{int(padding)}\0{int(max_resolution)}\0{xatlas.__version__}"
             f"\0{ALGORITHM_VERSION}".encode())
    if texels_per_unit > 0:  # keys without a density stay those of earlier versions
        h.update(f"\0{float(texels_per_unit)!r}".encode())
    return h.hexdigest()


# --------------------------------------------------------------------------- unwrap
def unwrap(positions: np.ndarray, triangles: np.ndarray, resolution: int, padding: int,
           cache_dir: Path | None = None, triangle_polygon: np.ndarray | None = None, *,
           max_resolution: int = 0, cancelled: Callable[[], bool] | None = None,
           progress: Callable[[str], None] | None = None, in_process: bool = False,
           texels_per_unit: float = 0.0) -> UnwrapResult:
    """Unwrap a mesh into non-overlapping light-map charts.

    Parameters
    ----------
    positions : (V, 3) float64 vertex positions (any consistent space; object-local
        keeps the cache valid when the object moves).
    triangles : (t, 3) int vertex indices; output keeps this order.
    resolution : light-map width and height in texels (typical 64-2048).
    padding : texels of gutter between charts (typical 2).
    cache_dir : folder for content-keyed ``unwrap-<sha256>.npz`` files, or None. A folder
        that cannot be written only costs the reuse (see ``UnwrapResult.warnings``).
    triangle_polygon : (t,) int, optional polygon (Blender face) of each triangle,
        e.g. ``MeshLoopTriangle.polygon_index``. When given, polygons that xatlas
        split across charts are re-joined so each polygon corner has one UV
        (see :func:`loop_uvs`).
    max_resolution : when the charts do not fit ``resolution``, grow the map (by 25 %
        steps) up to this size; ``UnwrapResult.resolution`` says what was used. 0: never grow.
    texels_per_unit : a texel density to hold, texels per unit of ``positions`` (the bake's
        Texel Density): the map grows past ``resolution``, up to ``max_resolution``, until the
        charts fit at this density instead of being scaled down into ``resolution``. 0: fit
        ``resolution`` (a resolution override, or no density).
    cancelled : called while xatlas runs; returning True kills it and raises
        ``core.executor.Cancelled``.
    progress : called with a short message when a step starts (e.g. a retry).
    in_process : run xatlas in this process (no crash protection; for tools and tests).

    Returns
    -------
    UnwrapResult

    Raises
    ------
    ValueError : on non-finite positions, indices out of range, bad shapes or a
        resolution/padding that leaves no room; :class:`DegenerateMeshError` when no
        triangle has an area.
    PackError : the charts do not fit ``max(resolution, max_resolution)``.
    UnwrapCrashed : xatlas crashed with every chart-option variant.
    UnwrapError : the layout still overlaps after repair.
    """
    p, tri, poly = _validated(positions, triangles, resolution, padding, triangle_polygon)
    if not (math.isfinite(texels_per_unit) and texels_per_unit >= 0):
        raise ValueError(f"unwrap: texels per unit must be finite and >= 0, got {texels_per_unit!r}")

    # -- content-keyed cache (STYLE principle 8); a damaged or overlapping entry is recomputed
    path = None
    if cache_dir is not None:
        key = cache_key(p, tri, resolution, padding, poly, max_resolution, texels_per_unit)
        path = Path(cache_dir) / f"unwrap-{key}.npz"
        cached = _load(path, len(tri))
        if cached is not None and uv_overlaps(cached.uv, None, cached.resolution, cached.resolution) == 0:
            return cached

    if len(tri) == 0:
        result = UnwrapResult(np.zeros((0, 3, 2), np.float32), 0, 0.0, chart=np.zeros(0, np.int32),
                              resolution=int(resolution))
    else:
        run = _layout_here if in_process else _layout_in_child
        out = run(p, tri, int(resolution), int(padding), poly, int(max_resolution), cancelled, progress,
                  float(texels_per_unit))
        result = UnwrapResult(out["uv"], out["chart_count"], out["utilization"], False, out["polygons_fixed"],
                              out["chart"], out["resolution"], out["polygons_detached"])
    # -- the gate: a light-map layout that overlaps is never returned
    overlaps = uv_overlaps(result.uv, None, result.resolution, result.resolution)
    if overlaps:
        raise UnwrapError(f"{overlaps} texel centres of the {result.resolution}x{result.resolution} light map lie "
                          f"inside two or more UV triangles after repair; a map of another size packs the charts "
                          f"anew (change the object's Resolution Override or the Texel Density a little), or give the "
                          f"object Light-Map UVs of your own; and please report this mesh")
    if path is not None:
        warning = _store(path, result)
        if warning:
            result = replace(result, warnings=(warning,))
    return result


def _validated(positions, triangles, resolution, padding, triangle_polygon):
    """(positions (V, 3) float64, triangles (t, 3) int64, polygon (t,) int64 or None), checked."""
    p = np.ascontiguousarray(positions, dtype=np.float64)
    tri = np.ascontiguousarray(triangles)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"unwrap: positions must be (V, 3), got {p.shape}")
    if tri.ndim != 2 or tri.shape[1] != 3 or (tri.size and not np.issubdtype(tri.dtype, np.integer)):
        raise ValueError(f"unwrap: triangles must be (t, 3) integers, got {tri.shape} {tri.dtype}")
    tri = tri.astype(np.int64)
    if not np.isfinite(p).all():
        bad = np.flatnonzero(~np.isfinite(p).all(axis=1))
        raise ValueError(f"unwrap: {len(bad)} vertex positions are non-finite (NaN or inf), first vertex {bad[0]}")
    if tri.size and (tri.min() < 0 or tri.max() >= len(p)):
        raise ValueError(f"unwrap: triangle indices out of range [0, {len(p)})")
    if resolution < 1 or padding < 0 or 2 * padding >= resolution:
        raise ValueError(f"unwrap: resolution {resolution} with padding {padding} leaves no room for charts")
    poly = None
    if triangle_polygon is not None:
        poly = np.ascontiguousarray(triangle_polygon, dtype=np.int64)
        if poly.shape != (len(tri),):
            raise ValueError(f"unwrap: triangle_polygon must be ({len(tri)},), got {poly.shape}")
    if len(tri):
        c = p[tri].astype(np.float32).astype(np.float64)  # as xatlas sees them
        area2 = np.linalg.norm(np.cross(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), axis=1)
        if not (area2 > 0).any():
            raise DegenerateMeshError(f"no triangle has an area (all {len(tri)} are degenerate; "
                                      f"is the object scaled to 0?)")
    return p, tri, poly


# --------------------------------------------------------------------------- running xatlas
def _layout_here(p, tri, resolution, padding, poly, max_resolution, cancelled, progress, texels_per_unit=0.0):
    from . import xatlas_charts

    try:
        return xatlas_charts.layout(p, tri, resolution, padding, poly, max_resolution, 0, texels_per_unit)
    except xatlas_charts.PackError as e:
        raise PackError(str(e), e.minimum) from None


def python_interpreter() -> str:
    """A Python interpreter for the child process: ``sys.executable`` under the bpy wheel,
    the Python Blender bundles (``sys.prefix``) when ``sys.executable`` is Blender itself."""
    exe = Path(sys.executable)
    if exe.name.lower().startswith("python") and exe.is_file():
        return str(exe)
    version = f"{sys.version_info.major}.{sys.version_info.minor}"
    prefix = Path(sys.prefix)
    for candidate in (prefix / "bin" / f"python{version}", prefix / "bin" / "python3", prefix / "bin" / "python",
                      prefix / "python.exe", prefix / "bin" / "python.exe"):
        if candidate.is_file():
            return str(candidate)
    raise UnwrapError(f"no Python interpreter found to run xatlas in (looked next to {sys.executable} and in "
                      f"{prefix})")


def _layout_in_child(p, tri, resolution, padding, poly, max_resolution, cancelled, progress, texels_per_unit=0.0):
    """:func:`core.xatlas_charts.layout` in a child process, retried with other chart options
    when it crashes. Arrays go through ``.npz`` files in a temporary folder."""
    crashes = []
    arrays = dict(positions=p, triangles=tri)
    if poly is not None:
        arrays["polygon"] = poly
    limit = CHILD_SECONDS_BASE + CHILD_SECONDS_PER_TRIANGLE * len(tri)
    for variant in range(CHART_VARIANTS):
        if progress is not None:
            progress("unwrapping (xatlas)" if variant == 0 else f"unwrapping again with chart options {variant}")
        request = dict(resolution=resolution, padding=padding, max_resolution=max_resolution, variant=variant,
                       texels_per_unit=texels_per_unit)
        answer, out = ask_child(request, arrays, cancelled, limit, "pdic-unwrap-")
        if answer is None:
            crashes.append(out)
            continue
        if answer.get("error") == "PackError":
            raise PackError(answer["message"], int(answer.get("minimum", 0)))
        if answer.get("error") == "ValueError":
            raise ValueError(answer["message"])
        if answer.get("error"):
            raise UnwrapError(f"xatlas failed: {answer['error']}: {answer['message']}")
        return dict(uv=out["uv"].astype(np.float32), chart=out["chart"].astype(np.int32),
                    **{k: answer[k] for k in ("chart_count", "utilization", "polygons_fixed",
                                              "polygons_detached", "resolution")})
    raise UnwrapCrashed(f"xatlas crashed on this mesh with all {CHART_VARIANTS} chart-option sets "
                        f"({'; '.join(crashes)}); a known xatlas bug (jpcy/xatlas#146) on some regular meshes, "
                        f"e.g. an ico sphere with 7 subdivisions: change the mesh (e.g. fewer subdivisions), give "
                        f"the object Light-Map UVs of your own (e.g. UV > Lightmap Pack into a new UV map), "
                        f"or turn off the object's Bake Light Map (it still casts shadows and bounces light)")


def ask_child(request: dict, arrays: dict, cancelled, time_limit: float, prefix: str) -> tuple[dict | None, object]:
    """Run ``core/unwrap_worker.py`` on ``request`` (JSON scalars) and ``arrays`` in a temporary folder.

    Returns (its status, its output arrays), ({"error": ..., "message": ...}, {}) when it reported
    an error, or (None, what happened) when it crashed or gave no answer within ``time_limit`` s.
    """
    with tempfile.TemporaryDirectory(prefix=prefix) as folder:
        folder = Path(folder)
        np.savez(folder / "input.npz", **arrays)
        (folder / "request.json").write_text(json.dumps(dict(request, sys_path=[s for s in sys.path if s])))
        code = _run_child(folder, cancelled, time_limit)
        status = folder / "status.json"
        if not status.is_file():
            return None, (f"no answer within {time_limit:.0f} s" if code is None
                          else _describe_exit(code, folder / "stderr.txt"))
        answer = json.loads(status.read_text())
        if answer.get("error"):
            return answer, {}
        with np.load(folder / "output.npz", allow_pickle=False) as data:
            return answer, {k: data[k] for k in data.files}


def _run_child(folder: Path, cancelled, time_limit: float) -> int | None:
    """Run the worker on ``folder``; returns its exit code, or None when it was killed for not
    answering within ``time_limit`` seconds. Kills it and raises ``core.executor.Cancelled``
    when ``cancelled()`` turns True."""
    from .executor import Cancelled

    worker = Path(__file__).resolve().parent / "unwrap_worker.py"
    env = dict(os.environ, PYTHONNOUSERSITE="1", PYTHONFAULTHANDLER="1")
    with open(folder / "stderr.txt", "wb") as err:
        child = subprocess.Popen([python_interpreter(), "-I", str(worker), str(folder)], stdin=subprocess.DEVNULL,
                                 stdout=subprocess.DEVNULL, stderr=err, env=env)
        try:
            answered, started = None, time.monotonic()
            while True:
                try:
                    return child.wait(timeout=POLL_SECONDS)
                except subprocess.TimeoutExpired:
                    if cancelled is not None and cancelled():
                        raise Cancelled("unwrap cancelled") from None
                    # The answer is written: a child still alive after that is stuck tearing xatlas
                    # down (seen once: xatlas::Destroy waiting for its threads); its answer stands.
                    if answered is None and (folder / "status.json").is_file():
                        answered = time.monotonic()
                    if answered is not None and time.monotonic() - answered > EXIT_GRACE_SECONDS:
                        return 0
                    if answered is None and time.monotonic() - started > time_limit:
                        return None  # killed below
        finally:
            if child.poll() is None:
                child.kill()
                child.wait()


def _describe_exit(code: int, stderr: Path) -> str:
    if code < 0:
        import signal

        try:
            return f"killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"killed by signal {-code}"
    tail = stderr.read_text(errors="replace").strip().splitlines()[-1:] if stderr.is_file() else []
    return f"exit code {code}" + (f": {tail[0]}" if tail else "")


# --------------------------------------------------------------------------- polygon corners
def loop_uvs(uv_corner: np.ndarray, triangle_loops: np.ndarray, loop_count: int,
             tolerance: float = 1e-6) -> tuple[np.ndarray, int]:
    """One UV per Blender loop (polygon corner) from per-triangle-corner UVs.

    Parameters
    ----------
    uv_corner : (t, 3, 2) float32 UVs of each loop triangle's corners.
    triangle_loops : (t, 3) int loop index of each corner (``MeshLoopTriangle.loops``).
    loop_count : number of loops of the mesh.
    tolerance : UV distance (in [0, 1] units) above which two UVs of a loop differ.

    Returns
    -------
    uv_loop : (loop_count, 2) float32; the UV of the first triangle corner using the
        loop; loops no triangle uses get (0, 0).
    conflicts : number of loops whose triangles gave UVs farther apart than
        ``tolerance`` (a polygon split across charts); 0 after :func:`unwrap`
        with ``triangle_polygon``.
    """
    uv = np.asarray(uv_corner, dtype=np.float32).reshape(-1, 2)
    loops = np.asarray(triangle_loops, dtype=np.int64).reshape(-1)
    if len(uv) != len(loops):
        raise ValueError(f"loop_uvs: {len(uv) // 3} UV triangles for {len(loops) // 3} loop triangles")
    if len(loops) and (loops.min() < 0 or loops.max() >= loop_count):
        raise ValueError(f"loop_uvs: loop index out of range [0, {loop_count})")
    uv_loop = np.zeros((loop_count, 2), np.float32)
    uv_loop[loops[::-1]] = uv[::-1]  # fancy assignment keeps the last write: reversed = first corner wins
    deviation = np.abs(uv - uv_loop[loops]).max(axis=1) if len(uv) else np.zeros(0)
    conflicts = len(np.unique(loops[deviation > tolerance]))
    return uv_loop, int(conflicts)


# --------------------------------------------------------------------------- cache files
_ARRAYS = ("uv", "chart")
_FIELDS = ("chart_count", "utilization", "polygons_fixed", "resolution", "polygons_detached")


def _load(path: Path, triangle_count: int) -> UnwrapResult | None:
    """The cached result, or None if missing, damaged (checksum) or not for this mesh."""
    entry = read_entry(path)
    if entry is None:
        return None
    header, arrays = entry
    try:
        uv = arrays["uv"].astype(np.float32)
        chart = arrays["chart"].astype(np.int32)
        fields = {k: header[k] for k in _FIELDS}
    except KeyError:
        return None
    if uv.shape != (triangle_count, 3, 2) or chart.shape != (triangle_count,) or not np.isfinite(uv).all():
        return None
    if uv.size and (uv.min() < 0 or uv.max() > 1) or not int(fields["resolution"]) > 0:
        return None
    return UnwrapResult(uv, int(fields["chart_count"]), float(fields["utilization"]), True,
                        int(fields["polygons_fixed"]), chart, int(fields["resolution"]),
                        int(fields["polygons_detached"]))


def _store(path: Path, result: UnwrapResult) -> str | None:
    """Write the cache file; a warning (str) instead of an error when the folder is unusable:
    the cache only saves time."""
    try:
        write_entry(path, {k: getattr(result, k) for k in _FIELDS}, {k: getattr(result, k) for k in _ARRAYS})
    except OSError as e:
        return (f"unwrap cache folder {str(path.parent)!r} cannot be written ({e.strerror or e}); "
                f"going on without caching the unwrap")
    return None
