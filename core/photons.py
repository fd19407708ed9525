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

from dataclasses import dataclass, fields

import numpy as np

from . import emission
from .albedo import albedo as albedo_at
from .executor import Executor, Progress, serial_executor
from .rays import TRANSPARENT_MAX_LAYERS, RayCaster
from .sampling import cosine_hemisphere, orthonormal_basis
from .scene import Scene

BATCH_PHOTONS = 65_536
"""Photons emitted per batch: large enough to keep Embree busy, small enough to cancel within ~0.1 s."""


@dataclass
class PhotonMap:
    """Stored photons, struct of arrays (N photons). See :attr:`BYTES_PER_PHOTON`.

    p : (N, 3) float32 scene-local hit position.
    n : (N, 3) float32 unit geometric normal on the side the photon arrived from.
    wi : (N, 3) float32 unit direction from the hit back toward the previous hit (or the light).
    power : (N, 3) float32 watts carried *into* this hit.
    d_prev : (N,) float32 distance to the previous hit (to the emission point for bounce 0).
    prev : (N,) int32 index of the previous photon on the path; -1 for a first hit.
    bounce : (N,) uint8 diffuse reflections before this hit: 0 = direct photon.
    triangle : (N,) int32 triangle hit.
    albedo : (N, 3) float32 linear albedo at the hit.
    w_sum : (N,) float32 cumulative Ward weight of the records around the photon (section 3.1).
    E_indirect_sum : (N, 3) float32 cumulative sum of w_k * E_k of those records.
    E_direct : (N, 3) float32 direct irradiance at the photon from shadow rays.
    emitted : photons emitted (the budget actually used).
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
    w_sum: np.ndarray
    E_indirect_sum: np.ndarray
    E_direct: np.ndarray
    emitted: int = 0

    BYTES_PER_PHOTON = 12 * 4 + 4 + 4 + 1 + 4 + 12 + 4 + 12 + 12  # = 101

    def __len__(self) -> int:
        return len(self.p)

    @property
    def nbytes(self) -> int:
        return sum(getattr(self, f.name).nbytes for f in fields(self) if isinstance(getattr(self, f.name), np.ndarray))

    @property
    def is_indirect(self) -> np.ndarray:
        """(N,) bool: photons that bounced at least once (the ones E_k estimates use)."""
        return self.bounce > 0

    @property
    def last_hit(self) -> np.ndarray:
        """(N, 3) float64 the previous hit point p_lh = p + wi * d_prev (Figure 3)."""
        return self.p.astype(np.float64) + self.wi.astype(np.float64) * self.d_prev[:, None].astype(np.float64)

    def E_indirect(self, index: np.ndarray | None = None) -> np.ndarray:
        """(N, 3) float64 interpolated indirect irradiance at each photon from the cache (0 where uncovered).

        index : photon indices (m,) to evaluate only those, (m, 3).
        """
        pick = slice(None) if index is None else index
        w = self.w_sum[pick].astype(np.float64)[:, None]
        return np.divide(self.E_indirect_sum[pick].astype(np.float64), w, out=np.zeros((len(w), 3)), where=w > 0)

    @staticmethod
    def empty(emitted: int = 0) -> "PhotonMap":
        return PhotonMap(*_allocate(0), emitted=emitted)


def _allocate(n: int) -> tuple:
    return (np.zeros((n, 3), np.float32), np.zeros((n, 3), np.float32), np.zeros((n, 3), np.float32),
            np.zeros((n, 3), np.float32), np.zeros(n, np.float32), np.full(n, -1, np.int32),
            np.zeros(n, np.uint8), np.zeros(n, np.int32), np.zeros((n, 3), np.float32),
            np.zeros(n, np.float32), np.zeros((n, 3), np.float32), np.zeros((n, 3), np.float32))


@dataclass(frozen=True)
class PhotonBatchResult:
    photons: PhotonMap
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
            rho = np.minimum(rho / np.maximum(1.0 - tau[tri], 1e-6)[:, None], 1.0)
        go = np.flatnonzero(passing)
        bounced = np.flatnonzero(~passing & (bounce < max_bounces))
        # Russian roulette on the albedo: survive with q = max channel, carry power * rho / q.
        q = rho[bounced].max(axis=1)
        bounced = bounced[rng.random(len(bounced)) < q]
        q = rho[bounced].max(axis=1)
        local = cosine_hemisphere(rng.random((len(bounced), 2)))[0]
        t1, t2 = orthonormal_basis(n[bounced])
        d_bounced = local[:, :1] * t1 + local[:, 1:2] * t2 + local[:, 2:3] * n[bounced]
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


def _assemble(waves: list, count: int) -> PhotonMap:
    pm = PhotonMap(*_allocate(count))
    start = 0
    for p, n, wi, phi, t, prev, bounce, tri, rho in waves:
        s = slice(start, start + len(p))
        pm.p[s], pm.n[s], pm.wi[s], pm.power[s] = p, n, wi, phi
        pm.d_prev[s], pm.prev[s], pm.bounce[s], pm.triangle[s], pm.albedo[s] = t, prev, bounce, tri, rho
        start = s.stop
    return pm


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


def concatenate(batches: list[PhotonMap], emitted: int) -> PhotonMap:
    """Stitch batches into one map, offsetting each batch's path links.

    Field by field, releasing each batch's copy as soon as it is stitched, so the
    peak is the map plus one field of the batches rather than two whole maps.
    """
    if not batches:
        return PhotonMap.empty(emitted)
    sizes = [len(b) for b in batches]
    starts = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
    total = int(sum(sizes))
    # The section 3.1 fields start at zero: fresh zeros cost no resident memory until
    # written (Preview never writes E_direct), where stitching them would touch every page.
    columns = {"w_sum": np.zeros(total, np.float32), "E_indirect_sum": np.zeros((total, 3), np.float32),
               "E_direct": np.zeros((total, 3), np.float32)}
    for f in fields(PhotonMap):
        if f.name == "emitted" or f.name in columns:
            continue
        parts = []
        for b, start in zip(batches, starts):
            value = getattr(b, f.name)
            if f.name == "prev":
                value = np.where(value >= 0, value + start, -1).astype(np.int32)
            parts.append(value)
            setattr(b, f.name, None)
        columns[f.name] = np.concatenate(parts)
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

    Returns the photon map (section 3.1 fields zeroed) and counters.
    """
    executor = executor or serial_executor()
    plan = emission.plan(scene, photons)
    if plan.total == 0:
        return PhotonMap.empty(), PhotonTraceStats(0, 0, 0, 0, {})
    batches = plan.batches(BATCH_PHOTONS)
    serial = caster.serial()
    done = [0]

    def run(job):
        index, batch = job
        rng = np.random.default_rng([seed, 1, index])
        o, d, phi, n0 = emission.emit(scene, batch, rng)
        result = trace_photon_batch(scene, serial, o, d, phi, n0, max_bounces, rng)
        done[0] += 1
        if progress is not None:
            progress.update(done[0] / len(batches))
        return result

    results = executor.map(run, list(enumerate(batches)))
    caster.rays_cast += sum(r.rays for r in results)
    photon_map = concatenate([r.photons for r in results], plan.total)
    release_free_memory()
    stats = PhotonTraceStats(plan.total, len(photon_map), sum(r.rays for r in results),
                             sum(r.escaped for r in results), plan.per_light())
    return photon_map, stats
