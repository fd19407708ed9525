"""A bake as a job of named steps, so the UI never blocks and a failure leaves no trace.

=========  ===========  ========================================================
step       thread       what
=========  ===========  ========================================================
choose     main (bpy)   validate; choose objects, output folder, resolutions;
                        estimate memory; read each target mesh's triangles
unwrap     worker       unwrap each mesh, or pack them into atlases (pure core;
                        progress, cancel)
extract    main (bpy)   write the UV maps ``PDIC_Lightmap``; extract the core scene
                        (atlas mode: each target baked over its atlas window)
compute    worker       ``core.pipeline.bake`` (pure core; progress, cancel)
finish     main (bpy)   write images (or atlases), manifest, records; swap in the
                        material copies
=========  ===========  ========================================================

:class:`JobRunner` runs the steps: all on one thread (the headless script, a
script's ``execute``) or stepwise from the modal operator's timer with the
worker steps on a thread. :meth:`BakeJob.prepare` (choose + unwrap + extract),
:meth:`compute`, :meth:`finish` and :meth:`run` remain for scripts and tests.

Every change to the file or the output folder is recorded in a
:class:`Transaction`; :meth:`BakeJob.rollback` undoes them in reverse order,
so an error or a cancel at any point leaves the .blend as it was.
"""
from __future__ import annotations

import json
import os
import threading
import time
from dataclasses import asdict, dataclass, field
from functools import partial
from pathlib import Path

import bpy
import numpy as np

from ..core import bake_cache
from ..core import manifest as core_manifest
from ..core import unwrap, user_uvs
from ..core.dask_executor import DaskUnavailable
from ..core.executor import Cancelled, Progress, make_executor
from ..core.lights import unused_portals
from ..core.scene import SceneError
from ..core.settings import BakeSettings
from . import atlas_bake, overlay, preferences, uvmaps, writeback
from .extract import extract_scene


class BakeError(Exception):
    """A bake cannot run or finish; the message is for the user and names the culprit."""


# --------------------------------------------------------------------------- transaction
class Transaction:
    """Undo log: each change registers how to undo it (and optionally what to do on commit)."""

    def __init__(self):
        self._entries: list = []

    def add(self, undo, label: str, commit=None) -> None:
        self._entries.append((undo, label, commit))

    def __len__(self):
        return len(self._entries)

    def rollback(self) -> list[str]:
        """Undo every change, newest first; returns messages of undo steps that failed."""
        errors = []
        while self._entries:
            undo, label, _ = self._entries.pop()
            try:
                undo()
            except Exception as e:  # keep undoing the rest
                errors.append(f"{label}: {e}")
        return errors

    def commit(self) -> None:
        """Keep every change; run the commit hooks (delete file backups and replaced datablocks).

        A failing hook leaves something stale behind (a backup file, a renamed-aside
        datablock) but never undoes the bake, so it is ignored.
        """
        entries, self._entries = self._entries, []
        for _, _, commit in entries:
            if commit is not None:
                try:
                    commit()
                except Exception:
                    pass


# --------------------------------------------------------------------------- helpers
def default_cache_dir() -> Path:
    """Where unwraps are cached: ``unwrap_cache`` in the preferences' cache folder
    (default: the extension's user folder, else the temp folder)."""
    return preferences.cache_dir(sub="unwrap_cache")


def records_file_for(plan: writeback.OutputPlan, scene_name: str) -> Path:
    """Where a bake's irradiance records go: next to the manifest (one file per .blend and
    scene, ``<blend>.pdic_records.<scene>.npz``), or (images packed into an unsaved .blend)
    ``records/<scene>.npz`` in the cache folder."""
    if not plan.pack:
        prefix = writeback.blend_key()
        stem = Path(overlay.RECORDS_FILENAME).stem
        return plan.directory / f"{prefix + '.' if prefix else ''}{stem}.{writeback.file_key(scene_name)}.npz"
    folder = preferences.cache_dir(sub="records")
    folder.mkdir(parents=True, exist_ok=True)
    return folder / (bpy.path.clean_name(scene_name) + ".npz")


def _blender_path(path: Path | None) -> str:
    """``path`` relative to the .blend (``//...``) when the .blend is saved and it lies beside it."""
    if path is None:
        return ""
    if bpy.data.filepath:
        try:
            return bpy.path.relpath(str(path))
        except ValueError:  # another drive (Windows)
            pass
    return str(path)


def _object_settings(obj):
    return getattr(obj, "pdic", None)


def _user_uv_map(mesh, users) -> str:
    """The UV map of ``mesh`` its users name as Light-Map UVs ("": unwrap it); BakeError when they
    name different maps, a map the mesh lacks, or PDIC's own (which Clear removes)."""
    names = {getattr(_object_settings(o), "uv_map", "") for o in users}
    if len(names) > 1:
        raise BakeError(f"objects {', '.join(repr(o.name) for o in users)} share mesh {mesh.name!r} but name "
                        f"different Light-Map UVs ({', '.join(repr(n or 'unwrap') for n in sorted(names))}): one "
                        f"mesh has one light-map layout; give them the same")
    name = names.pop()
    if not name:
        return ""
    if name == uvmaps.LIGHTMAP_UV:
        raise BakeError(f"object {users[0].name!r}: Light-Map UVs names {uvmaps.LIGHTMAP_UV!r}, the map PDIC writes "
                        f"and Clear removes; rename your layout (e.g. 'Lightmap') and name that")
    if name not in mesh.uv_layers:
        have = ", ".join(repr(l.name) for l in mesh.uv_layers) or "none"
        raise BakeError(f"object {users[0].name!r}: its Light-Map UVs {name!r} is not a UV map of mesh "
                        f"{mesh.name!r} (its UV maps: {have})")
    return name


def choose_objects(view_layer, candidates) -> tuple[list, list[str], list[str]]:
    """Split ``candidates`` into (bakeable objects, warnings, reasons for skipping)."""
    chosen, warnings, reasons = [], [], []
    for obj in candidates:
        reason = _skip_reason(view_layer, obj)
        if reason is None:
            chosen.append(obj)
            continue
        reasons.append(reason)
        if "library" in reason:
            warnings.append(reason)
    return chosen, warnings, reasons


def _skip_reason(view_layer, obj) -> str | None:
    """Why ``obj`` cannot get a light map in this view layer, or None."""
    settings = _object_settings(obj)
    if obj.name not in view_layer.objects or view_layer.objects[obj.name] != obj:
        scenes = ", ".join(repr(s.name) for s in obj.users_scene) or "no scene"
        return f"{obj.name!r} is not in view layer {view_layer.name!r} of this scene (it is in {scenes})"
    if obj.type != "MESH":
        return f"{obj.name!r} is not a mesh ({obj.type})"
    if settings is not None and not settings.bake:
        return f"{obj.name!r} has Bake Light Map off"
    if obj.hide_render:
        return f"{obj.name!r} is hidden from render"
    if obj.library is not None or obj.data.library is not None:
        lib = (obj.library or obj.data.library).filepath
        return f"{obj.name!r} is linked from library {lib!r}: its mesh cannot take a light-map UV map; skipped"
    if len(obj.data.polygons) == 0:
        return f"{obj.name!r} has no faces"
    return None


def baked_mesh_partners(view_layer, objects) -> list:
    """Objects sharing a mesh with ``objects`` that already have a light map laid out in its UV map.

    Re-unwrapping a shared mesh for some of its users would misalign the others' maps,
    so those are re-baked too.
    """
    meshes = {o.data for o in objects}
    chosen = set(objects)
    return [o for o in view_layer.objects if o is not None and o.type == "MESH" and o.data in meshes and o not in chosen
            and writeback.owned_images(o) and _skip_reason(view_layer, o) is None]


BYTES_PER_TEXEL_SAMPLE = 150
"""Texel sample in flight: position, normal, uv, indices (80 B, core/texels.py) plus direct and
indirect irradiance (2 x 24 B) and their splats; per light-map texel add 64 B of images."""
STORED_PER_EMITTED = 3.5
"""Stored photons per emitted photon, upper end: a closed albedo-0.7 box stores 3.2 (tests/test_photon_memory.py)."""
MEMORY_FRACTION = 0.8
"""A bake may plan to use at most this fraction of the machine's physical memory."""


def photon_bytes(settings: BakeSettings) -> float:
    """Bytes of the stored photons (pass 1) a bake is expected to hold at most."""
    from ..core.photons import PhotonMap

    stored = settings.photons * min(1 + settings.max_bounces, STORED_PER_EMITTED) if settings.indirect else 0
    return stored * PhotonMap.BYTES_PER_PHOTON


def memory_estimate(settings: BakeSettings, texels: int) -> int:
    """Bytes a bake's largest arrays need: stored photons and texel samples (plus 300 MB of working set)."""
    samples = texels * settings.texel_samples ** 2
    return int(photon_bytes(settings) + samples * BYTES_PER_TEXEL_SAMPLE + texels * 64 + 300e6)


def physical_memory() -> int:
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # not POSIX: assume a modest machine
        return 8 << 30


def _gib(n: float) -> str:
    return f"{n / (1 << 30):.3g} GiB"


def check_memory(settings: BakeSettings, texels: int, largest: str) -> None:
    """Refuse (BakeError naming the setting) a bake whose arrays would not fit in memory."""
    need, have = memory_estimate(settings, texels), physical_memory()
    if need <= MEMORY_FRACTION * have:
        return
    if photon_bytes(settings) >= need / 2:
        culprit = f"the Photons setting ({settings.photons:,} photons)"
    else:
        culprit = (f"the light-map resolution ({texels:,} texels in all, largest {largest}; lower Texel Density "
                   f"or Resolution)")
    raise BakeError(f"{culprit} needs about {_gib(need)} of memory; this machine has {_gib(have)}: "
                    f"lower it to stay under {_gib(MEMORY_FRACTION * have)}")


def _json_default(value):
    if hasattr(value, "tolist"):  # numpy scalar or array
        return value.tolist()
    return str(value)


@dataclass
class BakeReport:
    """What a finished bake produced (also what the manifest says)."""

    objects: list = field(default_factory=list)
    warnings: list = field(default_factory=list)
    stats: dict = field(default_factory=dict)
    output: writeback.OutputPlan | None = None
    manifest_path: Path | None = None
    records_path: Path | None = None


# --------------------------------------------------------------------------- the job
MAIN, WORKER = "main", "worker"
USER_ERRORS = (SceneError, uvmaps.UVMapError, writeback.WritebackError, ValueError, OSError)
"""Failures caused by the scene or the environment: reported as BakeError with their message."""
HALF_MAX = 65504.0
"""Largest finite half-float value: EXR_HALF light maps clamp brighter texels to it."""
TEXEL_DENSITY_WARN = 0.5
"""Warn when an unwrap's texels per unit fall below this fraction of the requested Texel Density:
padding and packing leave part of every map empty (Sponza one object at 4/m: 2.7/m)."""


class BakeJob:
    """One bake of a scene's objects, as the named steps of :attr:`STEPS`.

    Parameters
    ----------
    context : bpy.types.Context (scene, view layer, depsgraph, selection).
    settings : the frozen core settings (``properties.to_settings``).
    objects : objects to bake; None = the selected ones (``selected_only``) or
        every bakeable mesh in the view layer.
    output_folder : Blender path; default ``scene.pdic.output_folder`` or ``//pdic_lightmaps/``.
    image_format : "EXR_HALF" or "EXR_FLOAT"; default from ``scene.pdic``.
    cache_dir : unwrap cache folder (None: :func:`default_cache_dir`, from the add-on preferences).
    atlas_size : > 0 packs all objects into shared atlases of this size (:mod:`.atlas_bake`); 0 = a map
        each; default ``scene.pdic.atlas_size``.
    scheduler : Dask scheduler the heavy stages run on (``tcp://host:port``, ``local:N``); "" = the
        thread pool; None = the add-on preference.
    """

    STEPS = (("choose", MAIN), ("unwrap", WORKER), ("extract", MAIN), ("compute", WORKER), ("finish", MAIN))

    def __init__(self, context, settings: BakeSettings, objects=None, selected_only: bool = False,
                 output_folder: str | None = None, image_format: str | None = None, cache_dir=None,
                 atlas_size: int | None = None, scheduler: str | None = None):
        self.scene = context.scene
        self.view_layer = context.view_layer
        self.context = context
        self.settings = settings
        props = getattr(self.scene, "pdic", None)
        self.output_folder = output_folder or (props.output_folder if props else "//pdic_lightmaps/")
        self.image_format = image_format or (props.image_format if props else "EXR_HALF")
        self.explicit_objects = list(objects) if objects is not None else None
        self.selected_only = selected_only
        self.cache_dir = Path(cache_dir) if cache_dir is not None else default_cache_dir()
        # Resolved here, on the main thread: the worker steps must not touch bpy.
        self.bake_cache_dir = preferences.cache_dir(sub="bake_cache")
        self.scheduler = scheduler if scheduler is not None else preferences.scheduler()
        self.txn = Transaction()
        self.warnings: list[str] = []
        self.timings: dict[str, float] = {}
        self.unwraps: dict[str, dict] = {}
        self.objects: list = []
        self.resolutions: dict[str, tuple[int, int]] = {}
        self.resolution_overridden: set = set()  # meshes whose map side a user's override sets: not grown
        self.plan: writeback.OutputPlan | None = None
        self.meshes: dict = {}          # mesh name -> bpy mesh (main thread only)
        self.mesh_users: dict = {}      # mesh name -> names of the objects baked with it
        self.triangles: dict = {}       # mesh name -> uvmaps.MeshTriangles
        self.scales: dict = {}          # mesh name -> (3,) world scale of its first user
        self.uv_loops: dict = {}        # mesh name -> (loop_count, 2) light-map UVs, from the unwrap step
        self.user_uvs: dict = {}        # mesh name -> (UV map name, (loop_count, 2) UVs): Light-Map UVs of its own
        self.extraction = None
        self.result = None
        self.report: BakeReport | None = None
        self.atlas_size = int(atlas_size if atlas_size is not None else getattr(props, "atlas_size", 0))
        self.atlas_density: dict = {}   # object name -> texel density factor (atlas mode)
        self.atlas_layout = None        # core.atlas.AtlasLayout (atlas mode), from the unwrap step

    # ----------------------------------------------------------------- errors and the step wrapper
    @staticmethod
    def user_error(error: BaseException) -> BaseException:
        """The exception to show for ``error``: BakeError for scene/environment faults, else itself."""
        if isinstance(error, (BakeError, Cancelled)) or not isinstance(error, USER_ERRORS):
            return error
        return BakeError(str(error))

    def run_step(self, name: str, progress: Progress | None = None) -> None:
        """Run one step; on any failure roll back (main thread only) and raise :meth:`user_error`."""
        try:
            self._call(name, progress)
        except BaseException as e:
            self.rollback()
            converted = self.user_error(e)
            if converted is e:
                raise
            raise converted from e

    def _call(self, name: str, progress: Progress | None) -> None:
        start = time.perf_counter()
        step = getattr(self, "_" + name)
        if dict(self.STEPS)[name] == WORKER:  # worker steps report progress and check for cancel
            step(progress)
        else:
            step()
        self.timings[name] = time.perf_counter() - start

    # ----------------------------------------------------------------- step 1: choose (main)
    def _choose(self) -> None:
        objects = self._bakeable(self._candidates())
        self.plan = writeback.plan_output(self.output_folder)
        if self.plan.pack:
            self.warnings.append(self.plan.message)
        self._read_meshes(objects)
        self.objects = [o for o in objects if o.data.name in self.meshes]
        if not self.objects:
            raise BakeError("nothing to bake: no selected mesh has a triangle with area")
        for mesh_name in self.meshes:
            self._choose_resolution(mesh_name)
        if self.atlas_size:
            atlas_bake.refuse_shared_meshes(self.mesh_users)
            self.atlas_density = atlas_bake.density_scales(self)
        self._check_memory()
        if self.settings.indirect and self.settings.photons == 0:
            self.warnings.append("Photons is 0: the light maps hold direct light only (no indirect light)")
        # Joined objects (Ctrl+J) carry PDIC copies as mesh materials: give the user's back first.
        writeback.release_mesh_copies(self.txn)

    def _check_memory(self) -> None:
        largest = max(self.resolutions, key=lambda n: self.resolutions[n][0])
        check_memory(self.settings, self.texel_count, f"{largest!r} at {self.resolutions[largest][0]}^2")

    def _candidates(self) -> list:
        if self.explicit_objects is not None:
            return self.explicit_objects
        if len(self.scene.objects) and not len(self.view_layer.objects):
            # Objects a script linked into the scene's collections reach the view layer at its next update
            # (an operator does it; ``objects.link`` does not): without one the bake found nothing to bake.
            self.view_layer.update()
        if self.selected_only:
            candidates = [o for o in self.view_layer.objects
                          if o is not None and o.select_get(view_layer=self.view_layer)]
            if not candidates:
                raise BakeError("nothing to bake: no objects are selected (select meshes or bake all)")
            return candidates
        candidates = [o for o in self.view_layer.objects if o is not None]  # None: just deleted
        if not candidates:
            raise BakeError("nothing to bake: the view layer has no objects")
        return candidates

    def _bakeable(self, candidates) -> list:
        objects, warnings, reasons = choose_objects(self.view_layer, candidates)
        self.warnings += warnings
        if not objects:
            raise BakeError("nothing to bake: " + "; ".join(reasons[:5]) + (" ..." if len(reasons) > 5 else ""))
        for partner in baked_mesh_partners(self.view_layer, objects):
            shared = next(o for o in objects if o.data == partner.data)
            self.warnings.append(f"{partner.name!r} shares mesh {partner.data.name!r} with {shared.name!r} and has "
                                 f"a light map laid out in its UV map: re-baked too")
            objects.append(partner)
        meshes = {o.data for o in objects}
        for other in bpy.data.objects:
            if other.type == "MESH" and other.data in meshes and other not in objects and writeback.owned_images(other):
                self.warnings.append(f"{other.name!r} shares mesh {other.data.name!r} with this bake but cannot be "
                                     f"re-baked here ({_skip_reason(self.view_layer, other)}): its light map no "
                                     f"longer matches the new UV layout; bake or Clear it")
        editing = [o.name for o in objects if o.mode == "EDIT" or o.data.is_editmode]
        if editing:
            raise BakeError(f"leave Edit Mode before baking (editing {', '.join(map(repr, editing))})")
        return objects

    def _read_meshes(self, objects) -> None:
        """Each target mesh's triangles, once per mesh; meshes without area are left out (warned)."""
        by_mesh: dict = {}
        for obj in objects:
            by_mesh.setdefault(obj.data, []).append(obj)
        for mesh, users in by_mesh.items():
            tris = uvmaps.mesh_triangles(mesh)
            if not np.isfinite(tris.positions).all():
                bad = int((~np.isfinite(tris.positions).all(axis=1)).sum())
                raise BakeError(f"object {users[0].name!r} (mesh {mesh.name!r}): {bad} non-finite vertex "
                                f"coordinates (NaN or inf); fix or delete those vertices")
            if not (tris.surface_area((1.0, 1.0, 1.0)) > 0):
                for o in users:
                    self.warnings.append(f"{o.name!r}: mesh {mesh.name!r} has no triangle with area; not baked")
                continue
            self.meshes[mesh.name] = mesh
            self.mesh_users[mesh.name] = [o.name for o in users]
            self.triangles[mesh.name] = tris
            self.scales[mesh.name] = np.asarray(tuple(users[0].matrix_world.to_scale()), np.float64)
            own = _user_uv_map(mesh, users)
            if own:
                self.user_uvs[mesh.name] = (own, uvmaps.read_uv(mesh, own).astype(np.float64))

    def _choose_resolution(self, mesh_name: str) -> None:
        """Per-object override, else from the world surface area; one resolution per shared mesh."""
        mesh, users = self.meshes[mesh_name], [bpy.data.objects[n] for n in self.mesh_users[mesh_name]]
        tris, s = self.triangles[mesh_name], self.settings
        for obj in users:
            override = getattr(_object_settings(obj), "resolution", 0)
            if override > 0:
                res = int(override)
                self.resolution_overridden.add(mesh_name)
            else:
                area = tris.surface_area(tuple(obj.matrix_world.to_scale()))
                try:
                    if mesh_name in self.user_uvs:  # the layout is kept: the size alone sets the density
                        uv_area = unwrap.uv_areas(self._user_uv_corners(mesh_name)).sum()
                        if not uv_area > 0:
                            raise BakeError(f"object {obj.name!r}: its Light-Map UVs "
                                            f"{self.user_uvs[mesh_name][0]!r} have no area (every corner at one "
                                            f"point or on a line) or non-finite coordinates; lay them out, or "
                                            f"clear Light-Map UVs to let PDIC unwrap")
                        res = user_uvs.resolution_for(uv_area, area, s.texel_density, s.default_resolution,
                                                      s.min_resolution, s.max_resolution)
                    else:
                        res = unwrap.choose_resolution(area, s.texel_density, s.default_resolution,
                                                       s.min_resolution, s.max_resolution)
                except ValueError as e:
                    raise BakeError(f"object {obj.name!r}: texel density {s.texel_density!r} and surface "
                                    f"area {area!r} give no light-map resolution ({e})") from e
            self.resolutions[obj.name] = (res, res)
        sizes = {self.resolutions[o.name][0] for o in users}
        if len(sizes) > 1:  # one UV layout per mesh: share its resolution
            res = max(sizes)
            self.warnings.append(f"mesh {mesh.name!r} is shared by {', '.join(o.name for o in users)}: "
                                 f"all get {res}x{res} light maps")
            for o in users:
                self.resolutions[o.name] = (res, res)

    # ----------------------------------------------------------------- step 2: unwrap (worker, no bpy)
    def _unwrap(self, progress: Progress | None = None) -> None:
        """Unwrap each mesh once (positions scaled like its first user in the world), or (atlas
        mode) pack every object's charts into shared atlases."""
        progress = progress or Progress()
        progress.begin("Unwrapping")
        if self.atlas_size:
            self.atlas_layout = atlas_bake.unwrap_into_atlases(self, progress, partial(_unwrap_hooks, progress))
            return
        for i, (mesh_name, users) in enumerate(self.mesh_users.items()):
            if mesh_name in self.user_uvs:
                self._take_user_uvs(mesh_name, users)
            else:
                self._unwrap_mesh(mesh_name, users, progress, i / len(self.meshes))
            progress.update((i + 1) / len(self.meshes))
        self._check_memory()  # maps may have grown to hold the texel density

    def _unwrap_mesh(self, mesh_name: str, users: list, progress: Progress, fraction: float) -> None:
        """xatlas's charts for one mesh (positions scaled like its first user in the world)."""
        s, tris, res = self.settings, self.triangles[mesh_name], self.resolutions[users[0]][0]
        density = self._density_asked(mesh_name)
        try:
            result = unwrap.unwrap(tris.positions * self.scales[mesh_name], tris.triangles, res, s.padding,
                                   cache_dir=self.cache_dir, triangle_polygon=tris.polygon,
                                   max_resolution=max(s.max_resolution, res), texels_per_unit=density,
                                   **_unwrap_hooks(progress, mesh_name, fraction))
            uv_loop, conflicts = unwrap.loop_uvs(result.uv, tris.loops, tris.loop_count)
        except (ValueError, RuntimeError) as e:  # bad geometry (DegenerateMeshError), or xatlas failing to pack
            raise BakeError(f"cannot unwrap mesh {mesh_name!r} (object {users[0]!r}): {e}") from e
        self.warnings += list(result.warnings)
        if result.resolution != res:  # the map grew until the charts fit (at the texel density)
            if not density:
                self.warnings.append(f"mesh {mesh_name!r}: its charts do not fit {res}x{res}; light map "
                                     f"{result.resolution}x{result.resolution} instead")
            for name in users:
                self.resolutions[name] = (result.resolution, result.resolution)
        if conflicts:
            self.warnings.append(f"mesh {mesh_name!r}: {conflicts} polygon corners got split UVs")
        self.uv_loops[mesh_name] = uv_loop
        achieved = unwrap.achieved_texel_density(result.uv, tris.surface_area(self.scales[mesh_name]),
                                                 result.resolution)
        self._warn_below_density(mesh_name, achieved, density, "at that density its charts need",
                                 result.resolution)
        for name in users:
            self.unwraps[name] = {"charts": result.chart_count, "utilization": round(result.utilization, 4),
                                  "unwrap_cached": result.from_cache, "resolution_requested": res,
                                  "texel_density_achieved": round(achieved, 4)}

    def _take_user_uvs(self, mesh_name: str, users: list) -> None:
        """The mesh's own UV map (its users' Light-Map UVs) as its light-map layout, as it is laid out."""
        layout = self.checked_user_layout(mesh_name, users[0])
        tris, scale, res = self.triangles[mesh_name], self.scales[mesh_name], self.resolutions[users[0]][0]
        self.uv_loops[mesh_name] = self.user_uvs[mesh_name][1].astype(np.float32)
        achieved = unwrap.achieved_texel_density(layout.uv, tris.surface_area(scale), res)
        density, own = self._density_asked(mesh_name), self.user_uvs[mesh_name][0]
        too_small = self._warn_below_density(mesh_name, achieved, density, f"its UV map {own!r} needs", res)
        if density and not too_small and layout.density_median < user_uvs.UNEVEN_DENSITY * achieved:
            self.warnings.append(f"mesh {mesh_name!r}: half of its surface gets under {layout.density_median:.3g} "
                                 f"texels per unit of the {density:g} asked: the islands of its UV map {own!r} are "
                                 f"not scaled to their surface (small faces take the room); UV > Average Islands "
                                 f"Scale, then Pack Islands, evens them")
        for name in users:
            self.unwraps[name] = {"uv_source": own, "utilization": round(layout.utilization, 4),
                                  "resolution_requested": res, "texel_density_achieved": round(achieved, 4),
                                  "texel_density_median": round(layout.density_median, 4)}

    def _density_asked(self, mesh_name: str) -> float:
        """The Texel Density the mesh's map is meant to hold (0: its size is a user's Resolution Override)."""
        return 0.0 if mesh_name in self.resolution_overridden else self.settings.texel_density

    def _warn_below_density(self, mesh_name: str, achieved: float, density: float, needs: str, res: int) -> bool:
        """Warn (and say True) when the map, ``res`` texels a side, holds under TEXEL_DENSITY_WARN of the density
        asked; ``needs`` says what needs a larger map than that, the largest (e.g. "its UV map 'UV2' needs")."""
        if not (density and achieved < TEXEL_DENSITY_WARN * density):
            return False
        self.warnings.append(f"mesh {mesh_name!r}: its texels cover {achieved:.3g} per unit of the {density:g} "
                             f"asked: {needs} a map larger than {res}x{res}, the largest light map")
        return True

    def checked_user_layout(self, mesh_name: str, obj_name: str) -> user_uvs.UserUVLayout:
        """The mesh's own light-map UVs checked at its map size (worker thread: no bpy); BakeError if the
        bake cannot use them (outside 0-1, overlapping), a warning if some surface has no UV area."""
        name, _ = self.user_uvs[mesh_name]
        tris, res = self.triangles[mesh_name], self.resolutions[obj_name][0]
        where = f"object {obj_name!r}: its Light-Map UVs {name!r} (mesh {mesh_name!r})"
        try:
            layout = user_uvs.check_layout(self._user_uv_corners(mesh_name),
                                           tris.triangle_areas(self.scales[mesh_name]), res, where)
        except user_uvs.UserUVError as e:
            raise BakeError(str(e)) from e
        if layout.unmapped_area > 0:
            self.warnings.append(f"{where}: {100 * layout.unmapped_area:.2g} % of the surface lies on UV "
                                 f"triangles without area and gets no texels of its own")
        return layout

    def _user_uv_corners(self, mesh_name: str) -> np.ndarray:
        """(t, 3, 2) per-triangle-corner UVs of the mesh's own light-map UV map."""
        return self.user_uvs[mesh_name][1][self.triangles[mesh_name].loops]

    # ----------------------------------------------------------------- step 3: extract (main)
    def _extract(self) -> None:
        """Write the UV maps, then extract the core scene from the evaluated depsgraph, seeing the
        user's materials (not PDIC copies: their emission is the previous bake's light)."""
        for mesh_name, mesh in self.meshes.items():
            uvmaps.write_lightmap_uv(mesh, self.uv_loops[mesh_name], self.txn)
        showing = [o for o in self.scene.objects if writeback.is_baked_shading(o)]
        for obj in showing:  # registered first: undoing a switch that did not happen changes nothing
            self.txn.add(lambda obj=obj: writeback.set_shading([obj], baked=True), f"show baked lighting on {obj.name}")
        writeback.set_shading(showing, baked=False)
        depsgraph = self.context.evaluated_depsgraph_get()
        depsgraph.update()
        try:
            self.extraction = extract_scene(depsgraph, self.objects, uvmaps.LIGHTMAP_UV, self.resolutions)
        finally:  # objects that are not re-baked show their light maps again at once
            targets = {o.name for o in self.objects}
            writeback.set_shading([o for o in showing if o.name not in targets], baked=True)
        self.warnings += self.extraction.warnings  # extraction names degenerate triangles and dark scenes
        if self.settings.indirect and self.settings.photons > 0 and self.settings.deviations.portal_photons:
            for name in unused_portals(self.extraction.scene):  # deviation: portal-photons
                self.warnings.append(f"light portal {name!r} reaches outside the scene's bounds: PDIC sends no "
                                     f"photons through it (Cycles still uses it); move it onto its window")
        if self.atlas_layout is not None:
            self.extraction.scene = atlas_bake.window_scene(self.extraction.scene, self.atlas_layout)

    @property
    def texel_count(self) -> int:
        return int(sum(w * h for w, h in self.resolutions.values()))

    # ----------------------------------------------------------------- step 4: compute (worker, no bpy)
    def _compute(self, progress: Progress | None = None) -> None:
        from ..core import pipeline  # imported on first bake: keeps add-on registration light

        # Re-bakes of an unchanged scene reuse the photon map and cache (content-keyed, on disk
        # under the preferences' cache folder, pruned to its budget; not held in Blender's memory).
        store = bake_cache.BakeCache(self.bake_cache_dir, memory=False)
        try:
            executor = make_executor(self.settings.threads, self.scheduler)
        except DaskUnavailable as e:
            raise BakeError(str(e)) from e
        with executor:
            self.result = pipeline.bake(self.extraction.scene, self.settings, progress, executor, cache=store)
        store.prune()
        self.warnings += store.warnings  # e.g. a full cache folder: the bake went on without it

    # ----------------------------------------------------------------- step 5: finish (main)
    def _finish(self) -> None:
        start = time.perf_counter()
        writeback.ensure_directory(self.plan, self.txn)
        entries, new_outputs = [], []
        atlases = atlas_bake.write_atlas_images(self) if self.atlas_layout is not None else {}
        for name in self.extraction.target_objects:
            obj = bpy.data.objects.get(name)
            if obj is None:
                raise BakeError(f"object {name!r} was deleted or renamed during the bake")
            entry, image, copies = self._write_object(obj, atlas_bake.atlas_of(name, self.atlas_layout, atlases))
            entries.append(entry)
            new_outputs.append((obj, image, copies))
        self.timings["write_images"] = time.perf_counter() - start
        stats = self._stats()
        manifest_path = self._write_manifest(entries, stats)
        records_path = self._write_records()
        self._remember(stats, entries, manifest_path, records_path)
        self._swap_outputs(new_outputs, atlases)
        self.txn.commit()
        self.report = BakeReport(entries, list(self.warnings), stats, self.plan, manifest_path, records_path)

    def _write_object(self, obj, atlas=None) -> tuple[dict, object, list]:
        """One object's image file (or, atlas mode, its atlas's ``(image, relpath, pixels)``, written) and
        material copies (new datablocks, not shown yet); its manifest entry."""
        name = obj.name
        rebake = bool(writeback.owned_images(obj) or writeback.owned_materials(obj))
        if atlas is None:
            pixels = self._storable(name, self.result.lightmaps[name])
            temp = writeback.image_name(name) + writeback.TEMPORARY_SUFFIX if rebake else None
            image, relpath = writeback.write_image(name, pixels, self.plan, self.image_format, self.txn, name=temp)
        else:
            image, relpath, pixels = atlas
        copies, warnings = writeback.build_copies(obj, image, self.txn, temporary=rebake)
        self.warnings += warnings
        h, w = pixels.shape[:2]
        entry = dict(
            name=name, blend=os.path.basename(bpy.data.filepath), image=relpath,
            image_name=image.name.removesuffix(writeback.TEMPORARY_SUFFIX), uv_map=uvmaps.LIGHTMAP_UV,
            width=int(w), height=int(h),
            format="OPEN_EXR", color_depth=writeback.FORMATS[self.image_format], color_space="Non-Color",
            channels="RGBA", texels=int((self.result.lightmaps[name][..., 3] > 0).sum()),
            materials=[c.name.removesuffix(writeback.TEMPORARY_SUFFIX) for c in copies], **self.unwraps.get(name, {}))
        return entry, image, copies

    def _storable(self, name: str, pixels: np.ndarray) -> np.ndarray:
        """``pixels`` as the image format can hold them: half floats clamp at 65504 (said in a warning)."""
        if self.image_format != "EXR_HALF":
            return pixels
        rgb = pixels[..., :3]
        over = int((rgb > HALF_MAX).sum()) if np.isfinite(rgb).all() else 0
        if not over:
            return pixels
        self.warnings.append(f"{name!r}: {over} texel values exceed {HALF_MAX:g}, the largest half float, and are "
                             f"clamped in its EXR_HALF file (brightest {float(rgb.max()):.6g}); use EXR_FLOAT")
        clamped = pixels.copy()
        np.minimum(clamped[..., :3], HALF_MAX, out=clamped[..., :3])
        return clamped

    def _stats(self) -> dict:
        stats = dict(self.result.stats)
        stats["seconds"] = {**{f"addon_{k}": round(v, 4) for k, v in self.timings.items()},
                            **stats.get("seconds", {})}
        stats["texels"] = self.texel_count
        return stats

    def _write_manifest(self, entries: list, stats: dict) -> Path | None:
        """The folder's manifest: this bake's entries plus the previous ones still in use."""
        if self.plan.pack:
            return None
        folder, blend = self.plan.directory, os.path.basename(bpy.data.filepath)
        baked = {e["name"] for e in entries}

        def in_use(entry) -> bool:
            if "blend" in entry and entry["blend"] != blend:  # another .blend's map in a shared folder
                return (folder / str(entry.get("image", ""))).is_file()
            obj = bpy.data.objects.get(entry["name"])  # ours (or written before entries named their .blend)
            return entry["name"] not in baked and obj is not None and bool(writeback.owned_images(obj))

        objects = core_manifest.merge_objects(core_manifest.read_objects(folder), entries, in_use)
        path = folder / core_manifest.FILENAME
        writeback.replace_file(path, lambda p: core_manifest.write_manifest(
            p, objects, stats, asdict(self.settings), self.warnings), self.txn)
        return path

    def _write_records(self) -> Path:
        """The cache overlay's file: records p_k, n_k, E_k, R_k (zero records without indirect light)."""
        cache = self.result.cache
        K = len(cache) if cache is not None else 0
        fields = (cache.p, cache.n, cache.E, cache.R) if K else (np.zeros((0, 3)),) * 3 + (np.zeros(0),)
        path = records_file_for(self.plan, self.scene.name)
        origin = self.extraction.scene.origin_world
        writeback.replace_file(path, lambda p: overlay.save_records(p, *fields, origin, self.settings.a), self.txn)
        return path

    def _swap_outputs(self, new_outputs: list, atlases: dict) -> None:
        """Replace each object's previous outputs by the new ones and show them; every change is
        undoable until the commit, which deletes the replaced datablocks."""
        for obj, image, copies in new_outputs:
            writeback.retire_outputs(obj, {image, *copies}, self.txn, self.warnings)
            writeback.assign_copies(obj, copies, self.txn)
            if not atlases:
                writeback.rename(image, writeback.image_name(obj.name), self.txn)
            for copy in copies:
                writeback.rename(copy, copy.name.removesuffix(writeback.TEMPORARY_SUFFIX), self.txn)
        atlas_bake.swap_atlas_images(atlases, self.txn, self.warnings)
        # Atlases have no object: one still shown by an object not baked now is kept.
        kept = set(atlases) | atlas_bake.atlases_in_use({obj.name for obj, _, _ in new_outputs})
        for owner in writeback.orphaned_owners() - kept:  # outputs of deleted objects, unused atlases
            writeback.retire_outputs(owner, set(), self.txn, self.warnings)

    def _remember(self, stats: dict, entries: list, manifest_path, records_path) -> None:
        """Store the last bake's statistics and files in ``scene.pdic`` (undone on rollback)."""
        props = getattr(self.scene, "pdic", None)
        if props is None:
            return
        summary = dict(stats, objects=[e["name"] for e in entries], quality=self.settings.quality,
                       warnings=len(self.warnings), finished=time.strftime("%Y-%m-%d %H:%M:%S"))
        new = {"last_stats": json.dumps(summary, sort_keys=True, default=_json_default),
               "manifest_file": _blender_path(manifest_path), "records_file": _blender_path(records_path)}
        old = {k: getattr(props, k) for k in new}

        def undo(props=props, old=old):
            for k, v in old.items():
                setattr(props, k, v)

        self.txn.add(undo, "restore the last bake's statistics")
        for k, v in new.items():
            setattr(props, k, v)

    # ----------------------------------------------------------------- the public steps
    def prepare(self) -> None:
        """Main thread: choose, unwrap, extract. Raises BakeError (file unchanged) if the bake cannot start."""
        for name in ("choose", "unwrap", "extract"):
            self.run_step(name)

    def compute(self, progress: Progress | None = None) -> None:
        """Any thread; no bpy. Raises core.executor.Cancelled on cancel, SceneError on bad input
        (the caller rolls back, on the main thread)."""
        self._call("compute", progress)

    def finish(self) -> BakeReport:
        """Main thread: images, manifest, material copies. Raises BakeError after rolling back."""
        self.run_step("finish")
        return self.report

    def rollback(self) -> list[str]:
        """Undo everything the steps changed (safe to call more than once)."""
        return self.txn.rollback()

    def run(self, progress: Progress | None = None) -> BakeReport:
        """Every step on this thread (background mode, scripts)."""
        return JobRunner(self, progress).run()


def _unwrap_hooks(progress: Progress, mesh_name: str, fraction: float) -> dict:
    """``core.unwrap.unwrap``'s cancel and progress arguments for one mesh: a cancel kills
    its xatlas subprocess; its messages (e.g. a retry) become the stage, named by mesh."""
    def note(message: str) -> None:
        progress.begin(f"Unwrapping {mesh_name!r}: {message}")
        progress.update(fraction)

    return {"cancelled": progress.cancel_requested.is_set, "progress": note}


# --------------------------------------------------------------------------- the runner
class JobRunner:
    """Runs a :class:`BakeJob`'s steps: the panel's operator and the headless script both use it.

    :meth:`run` runs every step on the calling thread (it must be the main thread).
    :meth:`advance`, called repeatedly from the main thread (a modal timer), runs the
    main-thread steps itself and each worker step on a thread, returning True when
    the job has finished or failed (then :attr:`error` holds the user-facing error
    and the file is rolled back). ``progress`` reports stages and carries cancel.
    """

    def __init__(self, job: BakeJob, progress: Progress | None = None):
        self.job = job
        self.progress = progress or Progress()
        self.index = 0
        self.thread: threading.Thread | None = None
        self.error: BaseException | None = None
        self._worker_error: BaseException | None = None

    @property
    def done(self) -> bool:
        return self.error is not None or self.index >= len(self.job.STEPS)

    def run(self) -> BakeReport:
        for name, _ in self.job.STEPS:
            self.progress.check()
            self.job.run_step(name, self.progress)
        return self.job.report

    def advance(self) -> bool:
        """Main thread: move the job on as far as possible without blocking; True when done."""
        try:
            if self.thread is not None:
                if self.thread.is_alive():
                    return False
                self.thread = None
                if self._worker_error is not None:
                    raise self._worker_error
                self.index += 1
            while self.index < len(self.job.STEPS):
                self.progress.check()
                name, where = self.job.STEPS[self.index]
                if where == WORKER:
                    self._start_worker(name)
                    return False
                self.job.run_step(name, self.progress)
                self.index += 1
        except BaseException as e:
            self.job.rollback()
            self.error = self.job.user_error(e)
        return True

    def advance_to_worker(self) -> None:
        """Main thread: run the main-thread steps up to the first worker step; raise their error."""
        while self.index < len(self.job.STEPS) and self.job.STEPS[self.index][1] == MAIN:
            self.job.run_step(self.job.STEPS[self.index][0], self.progress)
            self.index += 1

    def _start_worker(self, name: str) -> None:
        def work():
            try:
                self.job._call(name, self.progress)
            except BaseException as e:  # handed to the main thread
                self._worker_error = e

        self.thread = threading.Thread(target=work, name=f"pdic-{name}", daemon=True)
        self.thread.start()

    def stop(self) -> None:
        """Main thread: cancel, wait for the worker, undo everything (before undo or loading a file)."""
        self.progress.cancel()
        if self.thread is not None:
            self.thread.join()
        self.job.rollback()
