"""Pass 1: the photon map (paper section 3.1, standard photon mapping [Jen96]).

Photons leave every light in proportion to its power, bounce diffusely with
Russian roulette on the textured albedo, and every diffuse hit is stored with
what passes 2 and 3 need: incident direction and distance to the previous hit
(to estimate R_k and re-project virtual rays), a link to the previous photon
of its path (whose irradiance gives a virtual ray its radiance), and the
section 3.1 fields w_sum, cumulative indirect irradiance and direct irradiance.

Tracing is a pure function over batches of emitted photons
(:func:`trace_photon_batch`), mapped on the executor; batches are stitched
together by offsetting their path links.
"""
from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

from . import emission
from .albedo import albedo as albedo_at
from .constants import REFLECTED_SHARE_FLOOR, STREAM_PHOTONS, TRANSPARENT_MAX_LAYERS
from .executor import Executor, Progress, serial_executor
from .lights import unused_portals
from .rays import RayCaster
from .sampling import cosine_directions
from .scene import Scene

BATCH_PHOTONS = 65_536
"""Photons emitted per batch: large enough to keep Embree busy, small enough to cancel within ~0.1 s."""


@dataclass(frozen=True)
class PhotonMap:
    """Stored photons, struct of arrays (N photons), immutable: pass 1's output, read by passes 2-3.

    p : (N, 3) float32 scene-local hit position.
    n : (N, 3) float32 unit geometric normal on the side the photon arrived from.
    wi : (N, 3) float32 unit direction from the hit back toward the previous hit (or the light).
    power : (N, 3) float32 watts carried *into* this hit.
    d_prev : (N,) float32 distance to the previous hit (to the emission point for bounce 0).
    prev : (N,) int32 index of the previous photon on the path; -1 for a first hit.
    bounce : (N,) uint8 diffuse reflections before this hit: 0 = direct photon.
    triangle : (N,) int32 triangle hit.
    albedo : (N, 3) float32 linear albedo at the hit.
    emitted : photons emitted (the budget actually used).

    The arrays are flagged read-only. What passes 2 and 3 learn about each photon (the
    section 3.1 fields) is a separate value, :class:`PhotonLighting`.
    """

    p: np.ndarray
    n: np.ndarray
    wi: np.ndarray
    power: np.ndarray
    d_prev: np.ndarray
    prev: np.ndarray
    bounce: np.ndarray
    triangle: np.ndarray
    albedo: np.ndarray
    emitted: int = 0

    BYTES_PER_PHOTON = 12 * 4 + 4 + 4 + 1 + 4 + 12 + 4 + 12 + 12  # = 101 with its PhotonLighting (28)

    def __post_init__(self):
        for f in fields(self):
            value = getattr(self, f.name)
            if isinstance(value, np.ndarray):
                value.flags.writeable = False

    def __setstate__(self, state):
        """Unpickled (a BakeCache on disk): read-only again, as when traced."""
        self.__dict__.update(state)
        self.__post_init__()

    def __len__(self) -> int:
        return len(self.p)

    @property
    def nbytes(self) -> int:
        """Bytes of the map and of its :class:`PhotonLighting` (what a bake holds per photon)."""
        return sum(getattr(self, f.name).nbytes for f in fields(self) if isinstance(getattr(self, f.name), np.ndarray)) \
            + PhotonLighting.BYTES_PER_PHOTON * len(self)

    @property
    def is_indirect(self) -> np.ndarray:
        """(N,) bool: photons that bounced at least once (the ones E_k estimates use)."""
        return self.bounce > 0

    @property
    def last_hit(self) -> np.ndarray:
        """(N, 3) float64 the previous hit point p_lh = p + wi * d_prev (Figure 3)."""
        return self.p.astype(np.float64) + self.wi.astype(np.float64) * self.d_prev[:, None].astype(np.float64)

    @staticmethod
    def empty(emitted: int = 0) -> "PhotonMap":
        return PhotonMap(*_allocate(0), emitted=emitted)


@dataclass(frozen=True)
class PhotonLighting:
    """The section 3.1 fields of every photon (N photons): what passes 2 and 3 learn about it.

    w_sum : (N,) float32 cumulative Ward weight of the records around the photon (Algorithm 1).
    E_indirect_sum : (N, 3) float32 cumulative sum of w_k * E_k of those records.
    E_direct : (N, 3) float32 direct irradiance at the photon from shadow rays (zero unless
        pass 3 reuses photon paths, which reads it).
    """

    w_sum: np.ndarray
    E_indirect_sum: np.ndarray
    E_direct: np.ndarray

    BYTES_PER_PHOTON = 4 + 12 + 12  # = 28

    @staticmethod
    def zeros(count: int) -> "PhotonLighting":
        """Fresh sums for Algorithm 1 (zeros cost no resident memory until written)."""
        return PhotonLighting(np.zeros(count, np.float32), np.zeros((count, 3), np.float32),
                              np.zeros((count, 3), np.float32))

    def E_indirect(self, index: np.ndarray | None = None) -> np.ndarray:
        """(N, 3) float64 interpolated indirect irradiance at each photon from the cache (0 where uncovered).

        index : photon indices (m,) to evaluate only those, (m, 3).
        """
        pick = slice(None) if index is None else index
        w = self.w_sum[pick].astype(np.float64)[:, None]
        return np.divide(self.E_indirect_sum[pick].astype(np.float64), w, out=np.zeros((len(w), 3)), where=w > 0)

    def radiance_out(self, albedo: np.ndarray) -> np.ndarray:
        """(N, 3) float64 radiance leaving each photon, albedo x (E_direct + E_indirect) / pi, W/m^2/sr."""
        E_total = self.E_direct.astype(np.float64) + self.E_indirect()
        return albedo.astype(np.float64) * E_total / np.pi


def _allocate(n: int) -> tuple:
    return (np.zeros((n, 3), np.float32), np.zeros((n, 3), np.float32), np.zeros((n, 3), np.float32),
            np.zeros((n, 3), np.float32), np.zeros(n, np.float32), np.full(n, -1, np.int32),
            np.zeros(n, np.uint8), np.zeros(n, np.int32), np.zeros((n, 3), np.float32))


@dataclass(frozen=True)
class PhotonBatchResult:
    photons: dict
    """PhotonMap field name -> array of the batch, ``prev`` local to it."""
    rays: int
    escaped: int


def trace_photon_batch(scene: Scene, caster: RayCaster, origins: np.ndarray, directions: np.ndarray,
                       power: np.ndarray, origin_normals: np.ndarray, max_bounces: int,
                       rng: np.random.Generator) -> PhotonBatchResult:
    """Trace one batch of emitted photons through up to ``max_bounces`` diffuse reflections.

    origins, directions : (m, 3) float64 emitted rays.
    power : (m, 3) float64 watts per photon.
    origin_normals : (m, 3) normal of the emitting surface (zero for free-space origins).
    Returns the stored hits with ``prev`` local to this batch.

    A hit on a transmissive triangle (``Geometry.transmission`` tau > 0) is stored, then the
    photon passes straight on with probability tau, keeping its power, bounce count and path
    link (its next hit's ``d_prev`` spans the layer), or else reflects with albedo rho / (1 - tau),
    the triangle's diffuse albedo given that it did not pass.
    """
    geometry_n = scene.geometry.face_normals()
    # deviation: transparent-shadows, docs/DEVIATIONS.md (an opaque scene draws no extra random number)
    tau = scene.geometry.transmission if scene.geometry.transmission.any() else None
    waves = []
    stored = rays = escaped = 0
    o, d, phi = origins, directions, power
    m0 = len(o)
    prev, bounce = np.full(m0, -1, np.int64), np.zeros(m0, np.int64)
    travelled, layers = np.zeros(m0), np.zeros(m0, np.int64)  # since the previous diffuse hit
    surface_n = origin_normals
    while len(o):
        hits = caster.intersect(o, d, normals=surface_n)
        rays += len(o)
        hit = hits.hit
        escaped += int((~hit).sum())  # photons leaving an open scene stop here
        # t is measured from the origin pushed off its surface: start from that point, or bounced
        # photons land up to epsilon off the surface they hit (measured: 1.7e-5 of the diagonal).
        o = caster.offset_origins(o, surface_n, d)
        o, d, phi, prev, bounce, travelled, layers = (a[hit] for a in (o, d, phi, prev, bounce, travelled, layers))
        t, tri, bary = hits.t[hit], hits.triangle[hit], hits.barycentric[hit]
        m = len(tri)
        if m == 0:
            break
        p = o + d * t[:, None]
        n = geometry_n[tri]
        # Surfaces are two-sided for light transport: store the normal of the side hit.
        flip = np.einsum("ij,ij->i", n, d) > 0
        n[flip] *= -1.0
        rho = albedo_at(scene, tri, bary).astype(np.float64)
        index = stored + np.arange(m)
        waves.append((p, n, -d, phi, travelled + t, prev, bounce, tri, rho))
        stored += m
        if tau is None:
            passing = np.zeros(m, bool)
        else:
            passing = (rng.random(m) < tau[tri]) & (layers < TRANSPARENT_MAX_LAYERS)
            rho = np.minimum(rho / np.maximum(1.0 - tau[tri], REFLECTED_SHARE_FLOOR)[:, None], 1.0)
        go = np.flatnonzero(passing)
        bounced = np.flatnonzero(~passing & (bounce < max_bounces))
        # Russian roulette on the albedo: survive with q = max channel, carry power * rho / q.
        q = rho[bounced].max(axis=1)
        bounced = bounced[rng.random(len(bounced)) < q]
        q = rho[bounced].max(axis=1)
        d_bounced = cosine_directions(rng.random((len(bounced), 2)), n[bounced])
        o = np.concatenate([p[go], p[bounced]])
        d = np.concatenate([d[go], d_bounced])
        phi = np.concatenate([phi[go], phi[bounced] * rho[bounced] / q[:, None]])
        prev = np.concatenate([prev[go], index[bounced]])
        bounce = np.concatenate([bounce[go], bounce[bounced] + 1])
        travelled = np.concatenate([travelled[go] + t[go], np.zeros(len(bounced))])
        layers = np.concatenate([layers[go] + 1, layers[bounced]])
        surface_n = np.concatenate([n[go], n[bounced]])
    photons = _assemble(waves, stored)
    return PhotonBatchResult(photons, rays, escaped)


def _assemble(waves: list, count: int) -> dict:
    """The batch's columns (PhotonMap field name -> array), filled wave by wave."""
    columns = dict(zip(_COLUMNS, _allocate(count)))
    start = 0
    for wave in waves:
        s = slice(start, start + len(wave[0]))
        for name, value in zip(_COLUMNS, wave):
            columns[name][s] = value
        start = s.stop
    return columns


_COLUMNS = ("p", "n", "wi", "power", "d_prev", "prev", "bounce", "triangle", "albedo")


def release_free_memory() -> None:
    """Hand memory freed by the tracing threads back to the operating system (glibc only).

    Each worker thread allocates its batches' temporaries in its own malloc arena, and
    glibc keeps freed arena memory for reuse: after tracing 4M photons on two threads
    the process held 780 to 1040 MB resident for the same 405 MB photon map, depending
    on how the threads interleaved. ``malloc_trim(0)`` returns the free pages; on other
    C libraries (macOS, Windows) this does nothing.
    """
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


def concatenate(batches: list[dict], emitted: int) -> PhotonMap:
    """Stitch batches (column dicts) into one map, offsetting each batch's path links.

    Field by field, releasing each batch's copy as soon as it is stitched, so the
    peak is the map plus one field of the batches rather than two whole maps.
    """
    if not batches:
        return PhotonMap.empty(emitted)
    sizes = [len(b["p"]) for b in batches]
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
    columns = {}
    for name in _COLUMNS:
        parts = []
        for b, start in zip(batches, starts):
            value = b.pop(name)
            if name == "prev":
                value = np.where(value >= 0, value + start, -1).astype(np.int32)
            parts.append(value)
        columns[name] = np.concatenate(parts)
        del parts
    return PhotonMap(**columns, emitted=emitted)


@dataclass(frozen=True)
class PhotonTraceStats:
    emitted: int
    stored: int
    rays: int
    escaped: int
    emitted_per_light: dict


def trace_photons(scene: Scene, caster: RayCaster, photons: int, max_bounces: int, seed: int,
                  executor: Executor | None = None, progress: Progress | None = None
                  ) -> tuple[PhotonMap, PhotonTraceStats]:
    """Pass 1: emit ``photons`` from all lights in proportion to their power and trace them.

    Returns the (immutable) photon map and counters.
    """
    executor = executor or serial_executor()
    plan = emission.plan(scene, photons)
    if plan.total == 0:
        return PhotonMap.empty(), PhotonTraceStats(0, 0, 0, 0, {})
    serial = caster.serial()

    def run(index, batch):
        rng = np.random.default_rng([seed, STREAM_PHOTONS, index])
        o, d, phi, n0 = emission.emit(scene, batch, rng)
        return trace_photon_batch(scene, serial, o, d, phi, n0, max_bounces, rng)

    results = executor.map_chunks(run, plan.batches(BATCH_PHOTONS), progress)
    caster.rays_cast += sum(r.rays for r in results)
    photon_map = concatenate([r.photons for r in results], plan.total)
    release_free_memory()
    stats = PhotonTraceStats(plan.total, len(photon_map), sum(r.rays for r in results),
                             sum(r.escaped for r in results), plan.per_light())
    return photon_map, stats


def trace_pass(scene: Scene, caster: RayCaster, settings, photon_bounces: int, executor: Executor,
               progress: Progress, stats) -> PhotonMap:
    """Pass 1 of a bake, with its progress stage and counters (``stats``: a BakeStats)."""
    progress.begin("Pass 1: tracing photons")
    if scene.portals and not settings.deviations.portal_photons:  # deviation: portal-photons
        scene = replace(scene, portals=())
    with stats.stage("photons"):
        photon_map, trace = trace_photons(scene, caster, settings.photons, photon_bounces, settings.seed,
                                          executor, progress)
    stats.set(photons_emitted=trace.emitted, photons_stored=trace.stored, photon_rays=trace.rays,
              photons_escaped=trace.escaped, photon_emitters=len(trace.emitted_per_light),
              max_bounces=settings.max_bounces, photon_bounces=photon_bounces, photon_bytes=photon_map.nbytes,
              bytes_per_photon=PhotonMap.BYTES_PER_PHOTON)
    if scene.portals:  # the portals the sun's and the world's photons were sent through
        stats.set(photon_portals=len(scene.portals) - len(unused_portals(scene)))
    return photon_map
