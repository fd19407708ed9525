"""The bake, as the paper's sequence of passes (STYLE.md principle 3).

:func:`bake` is the list of passes; each step below it is a few lines that hand one pass's
output (a value) to the next and memoise it in the :class:`~core.bake_cache.BakeCache`.
Where each pass's physics lives:

==========================  ==============================================================
rasterise texels            :mod:`core.texels`, :mod:`core.raster`
direct light                :mod:`core.direct` (shadow rays, chunked: ``shade_direct``)
pass 1: trace photons       :mod:`core.photons`, :mod:`core.emission`
pass 2: irradiance cache    :mod:`core.irradiance_cache` (Algorithm 1), :mod:`core.density`
pass 3: refine records      :mod:`core.refinement` (Figure 4), :mod:`core.virtual_rays`,
                            :mod:`core.real_rays`, :mod:`core.gather_cells`
interpolate + hole records  :mod:`core.hole_records` (section 3.4), :mod:`core.interpolation`
light maps                  :mod:`core.lightmaps` (splat, dilate)
==========================  ==============================================================

Heavy stages map pure functions over chunks with :meth:`Executor.map_chunks`; each chunk draws
its random numbers from ``default_rng([seed, stream, chunk])`` (streams: :mod:`core.constants`),
so results do not depend on the thread count or scheduling.
"""
from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.ndimage import binary_dilation

from . import texels as texel_stage
from .bake_cache import BakeCache, NoBakeCache, target_key, transport_key
from .contact import ContactFaces
from .constants import R_MIN_FLOOR, STREAM_DIRECT, STREAM_SKY, ZONE_PHOTONS
from .density import PhotonDensity
from .density_control import controlled_pass
from .direct import shade_direct
from .direct_footprint import footprint_direct
from .executor import TEXEL_CHUNK, Beside, Executor, HelpedExecutor, Progress, default_workers
from .hit_radiance import HitGrid
from .hole_records import indirect_at_texels, texel_verdicts
from .interpolation import CacheLookup
from .irradiance_cache import CacheParameters, IrradianceCache, cache_from_photons
from .lightmaps import write_lightmaps
from .photons import PhotonLighting, PhotonMap, trace_pass
from .rays import EmbreeClock, RayCaster
from .refinement import gather_sources, light_photons, refine_records
from .scene import Scene, SceneError, World
from .settings import BakeSettings
from .sky_gathering import gather_sky, gathered_sky
from .stats import BakeStats
from .validity import sample_validity
from .zone_grid import SharedZones


@dataclass
class BakeResult:
    """What a bake returns.

    lightmaps : target name -> (H, W, 4) float32 linear RGBA; RGB = E / pi (Cycles' Diffuse
        Direct+Indirect without colour), alpha = 1 where the texel is covered or dilated.
    centre_inside : target name -> (H, W) bool, texels whose centre lies on a triangle
        (the texels Cycles bakes, and those whose centre lies on a chart's right or upper edge,
        which it does not: comparisons use this mask and Cycles' own coverage).
    buried : target name -> (H, W) bool, covered texels partly or wholly inside closed geometry (a
        floor's texels a wall standing on it cuts or covers): Cycles bakes their footprint's mean
        with that part at 0, the light map holds their whole neighbours' light (deviation:
        buried-texels). Compare with Cycles through :meth:`as_cycles`.
    stats : JSON-ready statistics (see core/manifest.py).
    cache : the irradiance cache (None when indirect light was not baked).
    photons : the photon map (None when indirect light was not baked).
    photon_lighting : the photons' section 3.1 sums from passes 2-3 (None without photons).
    direct, indirect : target name -> (H, W, 3) float32 E / pi of each part, before dilation.
    coverage : target name -> (H, W) bool, texels covered before dilation (atlases composite these).
    """

    lightmaps: dict = field(default_factory=dict)
    centre_inside: dict = field(default_factory=dict)
    buried: dict = field(default_factory=dict)
    stats: dict = field(default_factory=dict)
    cache: IrradianceCache | None = None
    photons: PhotonMap | None = None
    photon_lighting: PhotonLighting | None = None
    direct: dict = field(default_factory=dict)
    indirect: dict = field(default_factory=dict)
    coverage: dict = field(default_factory=dict)

    def as_cycles(self, name: str) -> np.ndarray:
        """(H, W, 3) float32 ``name``'s direct + indirect E / pi as Cycles' bake holds it: each texel the
        mean over its footprint, parts inside closed geometry at 0 (the light map without the
        buried-texels deviation, before dilation). What comparisons with a Cycles bake read."""
        return self.direct[name] + self.indirect[name]


def bake(scene: Scene, settings: BakeSettings, progress: Progress | None = None,
         executor: Executor | None = None, cache: BakeCache | None = None) -> BakeResult:
    """Bake light maps for every target of ``scene``.

    cache : intermediates from earlier bakes to reuse, and where to store this bake's
        (:class:`~core.bake_cache.BakeCache`, content-keyed); None computes everything.
        An unchanged scene re-baked with the same cache traces no photon and casts no
        ray (counters ``photon_rays``, ``rays_cast`` are 0); changing one object's
        resolution redoes only that object's texels.
    """
    progress = progress or Progress()
    own_executor = executor is None
    executor = executor or Executor(settings.threads or default_workers())
    if not settings.deviations.transparent_shadows:  # deviation: transparent-shadows, docs/DEVIATIONS.md
        scene = replace(scene, geometry=replace(scene.geometry, transmission=None))  # every triangle opaque
    run = _Run(scene, settings, progress, executor, BakeStats(workers=executor.workers),
               cache if cache is not None else NoBakeCache())
    try:
        return _bake(run)
    finally:
        if own_executor:
            executor.close()


def _bake(run: "_Run") -> BakeResult:
    """The passes, in order."""
    _check_scene(run.scene)
    targets = rasterise_targets(run)
    run.stats.set(sky_gathered=int(run.sky is not None))  # deviation: sky-gathering
    cache = photons = lighting = None
    if run.settings.indirect and run.settings.photons > 0:
        params = cache_parameters(run.scene, [t.raster for t in targets], run.settings)
        # The direct light needs nothing of passes 2-3 or of the texels' indirect light: it runs beside
        # them, on the core pass 2's serial stretches leave idle (Sponza 16 texels/m: 11 of pass 2's 30
        # core-seconds), and on one thread, so the first target's texels' stage starts beside what is left
        # of it (Sponza at 2048^2, Preview: the bake waited 8-9 s for it with one core idle).
        beside = run.executor.in_process and run.executor.workers > 1
        direct = shade_direct_at_targets(run, targets, beside=beside)
        try:
            cache, photons, lighting = indirect_at_targets(run, targets, params, direct)
        except BaseException:
            direct.stop()
            raise
        direct()
    else:
        shade_direct_at_targets(run, targets)
        validity_without_indirect(run, targets)
    maps = write_lightmaps(run.scene, targets, run.settings.padding, run.progress, run.stats,
                           run.settings.deviations.buried_texels)
    return _finish(run, BakeResult(**maps, cache=cache, photons=photons, photon_lighting=lighting))


# --------------------------------------------------------------------------- the run's shared state
@dataclass
class _Run:
    """One bake's inputs and services: settings, progress, executor, statistics, memo store, BVH."""

    scene: Scene
    settings: BakeSettings
    progress: Progress
    executor: Executor
    stats: BakeStats
    store: BakeCache | NoBakeCache
    _caster: RayCaster | None = None
    _transport: str | None = None
    _contact: ContactFaces | None = None
    density: PhotonDensity | None = None
    """Pass 2's photon kd-tree when this run built it (hole records reuse it: it costs seconds)."""
    hit_grid: HitGrid | None = None
    """Pass 3's hit grid when this run built it (the hole records' grid reuses its direct light)."""

    @property
    def sky(self) -> np.ndarray | None:
        """The world's radiance when the records gather it for the direct light (deviation: sky-gathering)."""
        return gathered_sky(self.scene, self.settings)

    def transport(self) -> str:
        """Hash of what light transport depends on (memo keys); empty without a cache to key."""
        if self._transport is None:
            self._transport = transport_key(self.scene) if isinstance(self.store, BakeCache) else ""
        return self._transport

    def caster(self) -> RayCaster:
        """The BVH, built the first time some stage casts rays."""
        if self._caster is None:
            self.progress.begin("Building BVH")
            with self.stats.stage("bvh"):
                g = self.scene.geometry
                self._caster = RayCaster(g.positions, self.scene.extent, self.executor, g.transmission)
            self.stats.clock = self._caster.clock
        return self._caster

    def contact(self) -> ContactFaces | None:
        """The tests for texel samples no light reaches, faces that touch others face to face (deviation:
        contact-faces) and sheets over them (deviation: under-sheets), or None when both are switched off."""
        deviations = self.settings.deviations
        if not (deviations.contact_faces or deviations.under_sheets):
            return None
        if self._contact is None:
            self._contact = ContactFaces(self.scene.geometry.positions, self.caster(), deviations.contact_faces,
                                         deviations.under_sheets)
        return self._contact


class _Beside:
    """A stage of ``run`` on a thread of its own (:class:`~core.executor.Beside`): ``stage(side)`` on a copy
    of the run that computes on that one thread (a :class:`~core.executor.HelpedExecutor`: the bake's thread
    takes its chunks too once it waits for it), with its own statistics, ray count and Embree clock. Its
    random streams are its chunks' own, so it computes what it would in line.

    :meth:`start` starts it; calling it waits for it once (raising its error, or Cancelled), folds its
    statistics into ``run``'s and runs ``finish()``; :meth:`stop` ends it early. Called before anything
    started it (passes 2-3 were stored), it runs the stage in line, on the bake's own workers.
    """

    def __init__(self, run: "_Run", name: str, stage, finish):
        self.run, self.name, self.stage, self.finish = run, name, stage, finish
        self.view = run.caster().serial()
        self.view.clock = EmbreeClock()  # its time inside Embree is its own stage's, not the one it runs beside
        self.stats = BakeStats(workers=1, clock=self.view.clock)
        contact = run.contact()
        self.contact = None if contact is None else contact.view()  # the texels' stage tests samples meanwhile
        self.executor = HelpedExecutor()  # one thread, the stage's own, which the bake's helps once it waits
        side = replace(run, progress=Progress(), executor=self.executor, stats=self.stats, _caster=self.view,
                       _contact=self.contact)
        self._thread = Beside(lambda: stage(side), side.progress, run.progress)
        self._waited = False

    def start(self) -> None:
        self._thread.start()

    def __call__(self) -> None:
        if self._waited:
            return
        self._waited = True
        if not self._thread.started:
            self.stage(self.run)
        else:
            if self._thread.running:  # the bake waits for it: that time is the bake's own (seconds.direct_wait)
                with self.run.stats.stage(f"{self.name}_wait"):
                    self._thread.wait(help=self.executor.help)
            self._thread.wait()  # raises the stage's error, or Cancelled
            self.run.stats.fold(self.stats)
            self.run.caster().rays_cast += self.view.rays_cast
            if self.contact is not None:
                self.run.contact().absorb(self.contact)
        self.finish()

    def stop(self) -> None:
        """Stop the stage at its next chunk (the bake failed or was cancelled beside it)."""
        if not self._waited:
            self._waited = True
            self._thread.stop()


class _InLine:
    """What a stage that ran in line hands on in place of a :class:`_Beside`: nothing to start, wait for or stop."""

    def start(self) -> None:
        pass

    def __call__(self) -> None:
        pass

    def stop(self) -> None:
        pass


@dataclass
class TargetTexels:
    """One target's texel samples and what has been computed for them (per-target work list)."""

    points: texel_stage.TexelPoints
    raster: texel_stage.TargetRaster
    key: str
    """Content key of the target's texels (also seeds its random streams)."""
    texel_size: float = 0.0
    """World size of one of the target's texels (sqrt of its area per covered texel)."""
    E_direct: np.ndarray | None = None
    """(n, 3) float64 direct irradiance at the samples, W/m^2 (zeros until shaded)."""
    E_indirect: np.ndarray | None = None
    """(n, 3) float64 indirect irradiance at the samples, W/m^2 (zeros until interpolated)."""
    holes: IrradianceCache | None = None
    """Hole records placed for this target (section 3.4)."""
    indirect_weight: np.ndarray | None = None
    """(n,) float64 the samples' shares of their texels' indirect light (texel validity: none for a
    sample inside geometry); None until the indirect light is interpolated (then ``points.weight``)."""

    def __post_init__(self):
        self.E_direct = np.zeros((len(self.points), 3))
        self.E_indirect = np.zeros((len(self.points), 3))

    @property
    def stream(self) -> int:
        """A per-target random stream id from its content key: the same texels draw the same numbers
        whatever else is baked with them, so a target's light map can be reused on its own."""
        return int(self.key[:8], 16)


def _check_scene(scene: Scene) -> None:
    if not scene.targets:
        raise SceneError("nothing to bake: the scene has no bake targets")
    if not scene.has_light():
        raise SceneError("nothing emits light: add a light, an emissive material or a world colour")


def _finish(run: "_Run", result: BakeResult) -> BakeResult:
    stats = run.stats
    stats.set(rays_cast=run._caster.rays_cast if run._caster is not None else 0)
    if run._contact is not None:  # deviation: contact-faces (its BVHs count their own rays)
        stats.set(contact_rays=run._contact.rays_cast)
    stats.set(photon_rays=stats.counters.get("photon_rays", 0))
    stats.set(**run.store.counters())
    result.stats = stats.as_dict()
    return result


# --------------------------------------------------------------------------- texels
def rasterise_targets(run: "_Run") -> list[TargetTexels]:
    """Texel samples of every target (only the scene's targets: objects not baked are never rasterised)."""
    scene, settings, stats = run.scene, run.settings, run.stats
    stats.set(triangles=scene.geometry.count, targets=len(scene.targets),
              emissive_triangles=len(scene.emissive_triangles), lights=len(scene.lights))
    run.progress.begin("Rasterising texels")
    targets, rasterised = [], []

    def lift(target):
        rasterised.append(target.name)
        points, rasters = texel_stage.lift_texels(replace(scene, targets=(target,)), settings.texel_samples,
                                                  run.executor.map, settings.deviations.crease_folding,
                                                  settings.deviations.edge_folding, settings.direct_footprint_side)
        return points, rasters[0]

    with stats.stage("rasterise"):
        for target in scene.targets:
            # the foldings change the samples, not the texels: they join the key after the hash, so the
            # target's random streams (TargetTexels.stream, the hash's first digits) stay its texels'.
            folding = settings.deviations.crease_folding or settings.deviations.edge_folding
            key = target_key(scene, target, settings.texel_samples) + (
                "+crease-folding" if settings.deviations.crease_folding else "") + (
                "+edge-folding" if settings.deviations.edge_folding else "") + (
                f"+side{settings.direct_footprint_side:g}" if folding else "")
            # stored under the code's hash too (store.key), as every other kind: a raster of older code is never reused
            points, raster = run.store.memoise("raster", run.store.key("raster", key), lambda: lift(target))
            covered = max(int(raster.coverage.sum()), 1)
            texel_size = float(np.sqrt(scene.geometry.areas()[target.triangles].sum() / covered))
            targets.append(TargetTexels(points, raster, key, texel_size))
    stats.set(texel_samples=sum(len(t.points) for t in targets),
              texels_covered=int(sum(t.raster.coverage.sum() for t in targets)), targets_rasterised=len(rasterised),
              texel_samples_folded=sum(t.raster.folded for t in targets),
              texel_samples_past_edges=sum(t.raster.past_edges for t in targets))
    return targets


def cache_parameters(scene: Scene, rasters, settings: BakeSettings) -> CacheParameters:
    """R_min from the largest texel's world size, R_max from the scene diagonal."""
    areas = scene.geometry.areas()
    texel_size = 0.0
    for target, raster in zip(scene.targets, rasters):
        covered = max(int(raster.coverage.sum()), 1)
        texel_size = max(texel_size, float(np.sqrt(areas[target.triangles].sum() / covered)))
    R_max = settings.r_max_fraction * scene.extent
    R_min = min(settings.r_min_texels * texel_size, R_max)
    # Pass 2's E_k is normalised over the surface actually in the disc (deviation: surface-coverage):
    # Preview's light maps are those E_k, and standard gathering's hits read them. Final with photon-path
    # reuse keeps the plain kernel: its virtual rays carry a +4 % bias that the plain kernel's darkness
    # at narrow surfaces cancels, so correcting one alone makes it worse.
    deviations = settings.deviations
    coverage = deviations.surface_coverage and not (settings.refine and settings.reuse_photon_paths)
    return CacheParameters(a=settings.a, r_nearest=settings.r_nearest, R_min=max(R_min, R_MIN_FLOOR * scene.extent),
                           R_max=R_max, kernel_coverage=coverage,
                           wall_sectors=deviations.wall_sectors, neighbour_clamp=deviations.neighbour_clamp,
                           clamp_recovery=deviations.clamp_recovery,
                           record_visibility=deviations.record_visibility, leave_one_out=deviations.leave_one_out,
                           zone_photons=ZONE_PHOTONS if deviations.zone_photon_floor and not settings.refine else 0)


# --------------------------------------------------------------------------- direct light
def shade_direct_at_targets(run: "_Run", targets: list[TargetTexels], beside: bool = False
                            ) -> "_Beside | _InLine":
    """E_direct (n, 3) at every target's texel samples (zeros when direct light is off).

    beside : return a :class:`_Beside` that shades the targets whose direct light is not stored, on a
        thread of its own once started; calling it waits for them and stores them. Without it (or with
        nothing to shade) they are shaded in line and an :class:`_InLine` is returned.
    """
    settings, stats, store = run.settings, run.stats, run.store
    if not settings.direct:
        return _InLine()
    # deviation: sky-gathering: the records bring the world's light (indirect_at_targets adds it)
    lit = run.scene if run.sky is None else replace(run.scene, world=World())

    def shade(side: "_Run", index: int, t: TargetTexels):
        with side.stats.stage("direct"):
            p = t.points
            direct, counters = shade_direct(lit, side.caster(), p.p, p.n_shading, p.n_geometric,
                                            settings.direct_samples, settings.seed, (STREAM_DIRECT, t.stream),
                                            side.executor, side.progress, whole=True,
                                            budget=settings.deviations.light_budget)
            contact = side.contact()
            if contact is not None:  # deviations: contact-faces, under-sheets, docs/DEVIATIONS.md
                direct = replace(direct, E=np.where(contact.samples(p.p, p.triangle)[:, None], 0.0, direct.E))
            E = direct.E
            if settings.deviations.direct_footprint:  # deviation: direct-footprint, docs/DEVIATIONS.md
                E, more = footprint_direct(lit, side.caster(), index, p, t.raster, t.texel_size, direct,
                                           settings, t.stream, side.executor, side.progress, contact)
                counters.update(more)
        side.stats.add(**counters)
        return E

    todo = []  # (index, target, key) of the targets not stored; targets are scene.targets' order
    for index, t in enumerate(targets):
        key = _direct_key(run, t)
        stored = store.get("direct", key)
        if stored is None:
            todo.append((index, t, key))
        else:
            t.E_direct = stored

    def compute(side: "_Run"):
        if todo:
            side.progress.begin("Direct light")
        for index, t, key in todo:
            t.E_direct = shade(side, index, t)

    def finish():
        for _, t, key in todo:
            store.put("direct", key, t.E_direct)
        stats.set(targets_shaded_direct=len(todo))

    if not (beside and todo):
        compute(run)
        finish()
        return _InLine()
    return _Beside(run, "direct", compute, finish)


def _direct_key(run: "_Run", t: TargetTexels) -> str:
    """The bake cache's key of a target's direct light."""
    settings = run.settings
    return run.store.key("direct", run.transport(), t.key, settings.direct_samples, settings.seed,
                         settings.deviations.direct_footprint, settings.direct_footprint_side, run.sky is not None,
                         settings.deviations.contact_faces, settings.deviations.under_sheets,
                         settings.deviations.light_budget)


def validity_without_indirect(run: "_Run", targets: list[TargetTexels]) -> None:
    """Texel validity for a bake without indirect light, so its light map buries texels under walls too
    (deviation: buried-texels): the direct light alone would keep Cycles' dark line along every wall's foot.

    Only samples :func:`_voted` picks cast validity rays: the direct light's own evidence settles the
    lit ones; with no photons, no photon evidence overrules the others' back-face votes. Sets each target's
    ``indirect_weight`` (the share :func:`core.lightmaps.outside_shares` reads).
    """
    settings, store = run.settings, run.store
    deviations = settings.deviations
    if not (settings.direct and deviations.buried_texels and deviations.texel_validity):
        return

    def weights(index: int, t: TargetTexels):
        voted = _voted(t.E_direct, t.points.texel, t.raster.width, t.raster.height, settings.padding + 2)
        return sample_validity(run.scene, run.caster(), None, index, t.points, t.texel_size, t.stream, 0.0,
                               settings, run.executor, run.progress, run.stats, voted, run.contact(),
                               t.raster.centre_triangle)[1]

    for index, t in enumerate(targets):
        key = store.key("indirect", "validity without indirect light", _direct_key(run, t), deviations,
                        settings.padding)
        t.indirect_weight = store.memoise("indirect", key, lambda: weights(index, t))


def _voted(E_direct: np.ndarray, texel: np.ndarray, width: int, height: int, reach: int) -> np.ndarray:
    """(n,) bool the samples texel validity votes on in a bake without indirect light: those their own
    shadow rays did not find lit, in texels within ``reach`` texels of a lit sample's (the light map's
    dilation rings: the texels it may fill from lit ones).

    Lit means E_direct > 0 in a texel whose samples differ: a shadow-edge texel holds its footprint's
    mean at every sample (deviation: direct-footprint), a sample under the wall included (a texel lit
    evenly by the sun is voted on too). Away from lit texels a buried texel and its neighbours are
    dark alike. Past ``reach`` texels under a wall the texels count as whole and black, and the
    dilation averages them into the deepest buried ones: the ``reach / 2`` texels nearest the lit
    floor take its light, what a bilinear filter and the first mip levels read.
    """
    E = E_direct.sum(axis=1)
    size = width * height
    count = np.maximum(np.bincount(texel, minlength=size), 1)
    mean = np.bincount(texel, weights=E, minlength=size) / count
    spread = np.bincount(texel, weights=np.abs(E - mean[texel]) > 1e-12 * np.abs(mean[texel]), minlength=size) > 0
    lit = (E > 0) & spread[texel]
    near = (np.bincount(texel[lit], minlength=size) > 0).reshape(height, width)
    if reach > 0:  # grown ring by ring over the 8-neighbours, as core.dilate fills the light map (0: until full)
        near = binary_dilation(near, np.ones((3, 3), bool), iterations=reach)
    return ~lit & near.ravel()[texel]


# --------------------------------------------------------------------------- indirect light
def indirect_at_targets(run: "_Run", targets: list[TargetTexels], params: CacheParameters,
                        direct: "_Beside | _InLine | None" = None
                        ) -> tuple[IrradianceCache, PhotonMap | None, PhotonLighting | None]:
    """Passes 1-3 (only if some target still needs them), then Equation 3 with hole records at
    every target's texels. Returns the full cache (hole records included), the photon map and
    the photons' lighting. direct : the direct light to run beside passes 2-3 (:func:`shade_direct_at_targets`):
    started once the photons are traced (their tracing keeps every core busy), waited for after the first
    target's texels' stage."""
    direct = direct or _InLine()
    settings, store = run.settings, run.store
    photon_bounces = settings.max_bounces - 1 if settings.refine else settings.max_bounces
    photon_key = store.key("photons", run.transport(), settings.photons, photon_bounces, settings.seed,
                           *((settings.density_control, params) if settings.density_control else ()),
                           *((settings.deviations.portal_photons,) if run.scene.portals else ()))
    cache_key = store.key("cache", photon_key, params, settings.refine, settings.hemisphere_theta,
                          settings.hemisphere_phi, settings.reuse_photon_paths, settings.deviations)
    passes: list = []  # (cache, photons, lighting) once computed or read, plus what holes read
    keys = [store.key("indirect", cache_key, t.key, settings.gradients, settings.direct_footprint_side)
            for t in targets]
    stored = [store.get("indirect", key) for key in keys]  # None: this target's texels' stage runs
    verdicts: dict = {}  # target index -> its texel verdicts, once computed beside pass 2
    beside = _InLine()  # the verdicts' stage beside pass 2, once started

    def verdicts_beside(density: PhotonDensity) -> None:
        nonlocal beside
        todo = [(index, t) for index, t in enumerate(targets) if len(t.points) and stored[index] is None]
        beside = _start_verdicts(run, todo, density, params, verdicts)

    def passes_1_to_3():
        photons = store.memoise("photons", photon_key,
                                lambda: controlled_pass(trace_pass(run.scene, run.caster(), settings, photon_bounces,
                                                                   run.executor, run.progress, run.stats),
                                                        params, settings, run.progress, run.stats))
        direct.start()
        return build_cache(run, photons, params, verdicts_beside)

    def texels(index: int, t: TargetTexels, r: "_Run"):
        """Target ``index``'s texels' stage on run ``r`` (the bake's, or one beside it: workers, statistics, rays)."""
        (cache, _, _), (density, sources), shared = passes
        name = f"{r.scene.targets[index].name} ({index + 1} of {len(targets)})" if len(targets) > 1 else ""
        with r.progress.naming(name):
            return indirect_at_texels(r.scene, r.caster(), density, sources, cache, index, t.points, t.texel_size,
                                      t.stream, params, settings, r.executor, r.progress, r.stats, r.sky, r.contact(),
                                      t.raster.centre_triangle, verdicts.pop(index, None), shared)

    todo = {index for index in range(len(targets)) if stored[index] is None}
    try:
        if todo:  # passes 1-3, what hole records read, the shared zones; the verdicts computed beside pass 2
            passes.append(store.memoise("cache", cache_key, passes_1_to_3))
            passes.append(_hole_sources(run, passes[0], params))
            passes.append(SharedZones(passes[0][0].p, passes[0][0].R, params.a))
            beside()
            _texel_stages(run, [(index, targets[index]) for index in sorted(todo)], stored, texels)
        for index, t in enumerate(targets):  # rasterise_targets' list: scene.targets' order
            if index in todo:
                store.put("indirect", keys[index], stored[index])
            E, t.holes, t.indirect_weight = stored[index]
            t.E_indirect = E[:, :3]
            direct()  # a target whose indirect light was stored reaches here without the texels' stage
            if run.sky is not None:  # deviation: sky-gathering: the world's light belongs to the direct-light image
                t.E_direct = t.E_direct + (E[:, 3:] if E.shape[1] > 3 else _sky_without_records(run, t))
    except BaseException:
        beside.stop()
        raise
    run.stats.set(targets_shaded_indirect=len(todo))
    cache, photons, lighting = passes[0] if passes else (store.get("cache", cache_key) or (IrradianceCache(), None, None))
    run.stats.set(hole_records=int(sum(len(t.holes) for t in targets if t.holes is not None)))
    cache = IrradianceCache.concatenate([cache, *(t.holes for t in targets if t.holes is not None and len(t.holes))])
    run.stats.set(records_total=len(cache))
    return cache, photons, lighting


def _texel_stages(run: "_Run", todo: list, stored: list, texels) -> None:
    """``stored[index] = texels(index, target, run)`` for every (index, target) of ``todo``: the bake's thread
    takes the largest targets first, and with two or more workers a thread beside it (a :class:`_Beside`,
    serial) the smallest, those of one chunk of samples (TEXEL_CHUNK). Such a target runs its lookups,
    hole records and crevices in one chunk each, on one core: a storeroom of 304 objects kept 1.4 of 2
    cores busy. A larger one stays on the bake's workers, which it keeps busy. Each target's stage reads
    only the shared records and its own samples and draws its chunks' own random streams, so which thread
    runs it changes nothing in its light."""
    queue = deque(index for index, t in sorted(todo, key=lambda it: -len(it[1].points)))
    targets = dict(todo)
    lock = threading.Lock()

    def take(largest: bool):
        with lock:
            if not queue or not (largest or len(targets[queue[-1]].points) <= TEXEL_CHUNK):
                return None
            return queue.popleft() if largest else queue.pop()

    side = _InLine()
    if len(todo) > 1 and run.executor.in_process and run.executor.workers > 1:
        def compute(side_run: "_Run"):
            start = time.perf_counter()
            while (index := take(False)) is not None:
                stored[index] = texels(index, targets[index], side_run)
            # Its stages overlap the bake's own: one stage beside them, ``texels``.
            stats = side_run.stats
            stats.seconds = {"texels": time.perf_counter() - start}
            stats.embree_seconds = {"texels": sum(stats.embree_seconds.values())}

        side = _Beside(run, "texels", compute, lambda: None)
        side.start()
    try:
        while (index := take(True)) is not None:
            stored[index] = texels(index, targets[index], run)
    except BaseException:
        side.stop()
        raise
    side()  # waits for the targets beside (raising their error), folds their statistics


def _start_verdicts(run: "_Run", todo: list, density: PhotonDensity, params: CacheParameters,
                    verdicts: dict) -> "_Beside | _InLine":
    """Start the texel verdicts (:func:`texel_verdicts`) of ``todo`` [(index, target), ...], the targets whose
    indirect light is not stored, on a thread of their own beside pass 2 (they need the photons, not the
    records: Sponza 16 texels/m leaves a core idle for ~7 s there, besides what the direct light fills),
    into ``verdicts`` (index -> verdicts). Nothing to do, or not on this process's cores: in line later."""
    if not (todo and run.executor.in_process and run.executor.workers > 1):
        return _InLine()

    def compute(side: "_Run"):
        for index, t in todo:
            verdicts[index] = texel_verdicts(side.scene, side.caster(), density, index, t.points, t.texel_size,
                                             t.stream, params, run.settings, side.executor, side.progress,
                                             side.stats, side.contact(), t.raster.centre_triangle)

    beside = _Beside(run, "verdicts", compute, lambda: None)
    beside.start()
    return beside


def _sky_without_records(run: "_Run", t: TargetTexels) -> np.ndarray:
    """(n, 3) the world's direct light at a target's samples by shadow rays, for a bake that was to gather
    it with its records but has none (no photon stayed in the scene): what the direct stage left out."""
    scene = run.scene
    world_only = replace(scene, lights=(), materials=replace(scene.materials,
                                                             emission=np.zeros_like(scene.materials.emission)))
    p = t.points
    E, counters = shade_direct(world_only, run.caster(), p.p, p.n_shading, p.n_geometric, run.settings.direct_samples,
                               run.settings.seed, (STREAM_DIRECT, t.stream), run.executor, run.progress)
    run.stats.add(**counters)
    return E


def build_cache(run: "_Run", photons: PhotonMap, params: CacheParameters, density_ready=None
                ) -> tuple[IrradianceCache, PhotonMap, PhotonLighting | None]:
    """Pass 2 (Algorithm 1) and, for Final quality, pass 3: (cache, photons, the photons' lighting).
    density_ready : called with the photons' :class:`PhotonDensity` before Algorithm 1 starts, or None."""
    if len(photons) == 0:
        return IrradianceCache(), photons, None
    settings, progress, stats = run.settings, run.progress, run.stats
    progress.begin("Pass 2: irradiance cache")
    with stats.stage("cache"):
        density = PhotonDensity(photons, run.executor.workers)
        if density_ready is not None:
            density_ready(density)
        cache, zones, lighting, build = cache_from_photons(density, params, settings.seed, progress, run.caster())
    stats.set(records=build.records, kd_queries=build.kd_queries, R_min=params.R_min, R_max=params.R_max,
              wall_rays=build.wall_rays, photons_uncovered_after_clamp=sum(build.uncovered_after_clamp))
    run.density = density  # reused by the hole records of this bake (its kd-tree costs seconds)
    if not settings.refine and run.sky is not None:  # deviation: sky-gathering: Preview's records gather it
        with stats.stage("cache"):
            cache, rays = gather_sky(run.caster(), cache, run.sky, params.a, params.R_min,
                                     settings.deviations.gradient_limiting, settings.seed, (STREAM_SKY, 0),
                                     run.executor, progress)
        stats.add(sky_rays=rays)
    if settings.refine:
        progress.begin("Pass 3: refining records")
        lighting = light_photons(run.scene, run.caster(), photons, lighting, settings, run.executor, progress, stats)
        with stats.stage("refine"):
            sources, grid_counters = gather_sources(density, lighting, cache, params, settings, run.scene,
                                                    run.caster(), run.executor, progress, sky=run.sky)
            progress.begin("Pass 3: refining records")
            cache, counters = refine_records(run.scene, run.caster(), sources, cache, zones, settings, params,
                                             run.executor, progress)
        stats.add(**counters, **grid_counters)
        run.hit_grid = sources.hit_grid
    return cache, photons, lighting


def _hole_sources(run: "_Run", entry, params: CacheParameters):
    """(PhotonDensity or None, GatherSources or None) that hole records read."""
    cache, photons, lighting = entry
    if photons is None or len(photons) == 0:
        return None, None
    density = run.density if run.density is not None else PhotonDensity(photons, run.executor.workers)
    sources = None
    if run.settings.refine:  # hole records' gathering reads indirect light from the refined cache
        sources, counters = gather_sources(density, lighting, cache, params, run.settings, run.scene, run.caster(),
                                           run.executor, run.progress, use=1, direct_from=run.hit_grid, sky=run.sky)
        run.stats.add(**{f"holes_{key}": value for key, value in counters.items()})
    return density, sources


__all__ = ["bake", "BakeResult", "cache_parameters", "build_cache", "CacheLookup", "PhotonLighting"]
