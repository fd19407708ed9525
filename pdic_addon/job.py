"""A bake as a job in three steps, so the UI never blocks and a failure leaves no trace.

1. :meth:`BakeJob.prepare` (main thread, bpy): validate, choose objects and
   resolutions, unwrap each target mesh into the UV map ``PDIC_Lightmap``,
   evaluate the depsgraph and extract the core scene.
2. :meth:`BakeJob.compute` (any thread, pure core): ``core.pipeline.bake``.
3. :meth:`BakeJob.finish` (main thread, bpy): write images, the manifest and
   the material copies.

Every change to the file or the output folder is recorded in a
:class:`Transaction`; :meth:`BakeJob.rollback` undoes them in reverse order,
so an error or a cancel at any point leaves the .blend as it was.
"""
from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import bpy
import numpy as np

from ..core import bake_cache
from ..core import manifest as core_manifest
from ..core import unwrap
from ..core.executor import Progress
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
        """Keep every change; run the commit hooks (e.g. delete file backups)."""
        entries, self._entries = self._entries, []
        for _, _, commit in entries:
            if commit is not None:
                try:
                    commit()
                except OSError:
                    pass


# --------------------------------------------------------------------------- helpers
def default_cache_dir() -> Path:
    """Where unwraps are cached: ``unwrap_cache`` in the preferences' cache folder
    (default: the extension's user folder, else the temp folder)."""
    return preferences.cache_dir(sub="unwrap_cache")


def records_file_for(plan: writeback.OutputPlan, scene_name: str) -> Path:
    """Where a bake's irradiance records go: next to the manifest, or (images packed
    into an unsaved .blend) ``records/<scene>.npz`` in the cache folder."""
    if not plan.pack:
        return plan.directory / overlay.RECORDS_FILENAME
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


def choose_objects(view_layer, candidates) -> tuple[list, list[str], list[str]]:
    """Split ``candidates`` into (bakeable objects, warnings, reasons for skipping)."""
    chosen, warnings, reasons = [], [], []
    for obj in candidates:
        settings = _object_settings(obj)
        if obj.type != "MESH":
            reasons.append(f"{obj.name!r} is not a mesh ({obj.type})")
        elif settings is not None and not settings.bake:
            reasons.append(f"{obj.name!r} has Bake Light Map off")
        elif obj.hide_render:
            reasons.append(f"{obj.name!r} is hidden from render")
        elif obj.library is not None or obj.data.library is not None:
            lib = (obj.library or obj.data.library).filepath
            msg = f"{obj.name!r} is linked from library {lib!r}: its mesh cannot take a light-map UV map; skipped"
            warnings.append(msg)
            reasons.append(msg)
        elif len(obj.data.polygons) == 0:
            reasons.append(f"{obj.name!r} has no faces")
        else:
            chosen.append(obj)
    return chosen, warnings, reasons


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
class BakeJob:
    """One bake of a scene's objects.

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
    """

    def __init__(self, context, settings: BakeSettings, objects=None, selected_only: bool = False,
                 output_folder: str | None = None, image_format: str | None = None, cache_dir=None,
                 atlas_size: int | None = None):
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
        # Resolved here, on the main thread: compute() runs in a worker and must not touch bpy.
        self.bake_cache_dir = preferences.cache_dir(sub="bake_cache")
        self.txn = Transaction()
        self.warnings: list[str] = []
        self.timings: dict[str, float] = {}
        self.unwraps: dict[str, dict] = {}
        self.objects: list = []
        self.resolutions: dict[str, tuple[int, int]] = {}
        self.plan: writeback.OutputPlan | None = None
        self.extraction = None
        self.result = None
        self.report: BakeReport | None = None
        self.atlas_size = int(atlas_size if atlas_size is not None else getattr(props, "atlas_size", 0))
        self.atlas_layout = None

    # ----------------------------------------------------------------- 1. prepare
    def prepare(self) -> None:
        """Main thread. Raises BakeError (file unchanged) if the bake cannot start."""
        try:
            self._prepare()
        except BaseException as e:
            self.rollback()
            if isinstance(e, (SceneError, uvmaps.UVMapError, writeback.WritebackError, ValueError)):
                raise BakeError(str(e)) from e
            raise

    def _prepare(self):
        start = time.perf_counter()
        if self.explicit_objects is not None:
            candidates = self.explicit_objects
        elif self.selected_only:
            candidates = [o for o in self.view_layer.objects if o.select_get(view_layer=self.view_layer)]
            if not candidates:
                raise BakeError("nothing to bake: no objects are selected (select meshes or bake all)")
        else:
            candidates = list(self.view_layer.objects)
            if not candidates:
                raise BakeError("nothing to bake: the view layer has no objects")
        objects, warnings, reasons = choose_objects(self.view_layer, candidates)
        self.warnings += warnings
        if not objects:
            raise BakeError("nothing to bake: " + "; ".join(reasons[:5]) + (" ..." if len(reasons) > 5 else ""))
        editing = [o.name for o in objects if o.mode == "EDIT" or o.data.is_editmode]
        if editing:
            raise BakeError(f"leave Edit Mode before baking (editing {', '.join(map(repr, editing))})")
        self.objects = objects
        # Output folder: validated before anything changes.
        self.plan = writeback.plan_output(self.output_folder)
        if self.plan.pack:
            self.warnings.append(self.plan.message)

        # -- resolutions: per-object override, else from the world surface area
        s = self.settings
        by_mesh: dict = {}
        for obj in objects:
            by_mesh.setdefault(obj.data, []).append(obj)
        triangles = {}
        for mesh, users in list(by_mesh.items()):
            tris = uvmaps.mesh_triangles(mesh)
            if not np.isfinite(tris.positions).all():
                bad = int((~np.isfinite(tris.positions).all(axis=1)).sum())
                raise BakeError(f"object {users[0].name!r} (mesh {mesh.name!r}): {bad} non-finite vertex "
                                f"coordinates (NaN or inf); fix or delete those vertices")
            if not (tris.surface_area((1.0, 1.0, 1.0)) > 0):
                for o in users:
                    self.warnings.append(f"{o.name!r}: mesh {mesh.name!r} has no triangle with area; not baked")
                del by_mesh[mesh]
                continue
            triangles[mesh] = tris
            for obj in users:
                override = getattr(_object_settings(obj), "resolution", 0)
                if override > 0:
                    res = int(override)
                else:
                    area = tris.surface_area(tuple(obj.matrix_world.to_scale()))
                    res = unwrap.choose_resolution(area, s.texel_density, s.default_resolution,
                                                   s.min_resolution, s.max_resolution)
                self.resolutions[obj.name] = (res, res)
            sizes = {self.resolutions[o.name][0] for o in users}
            if len(sizes) > 1:  # one UV layout per mesh: share its resolution
                res = max(sizes)
                self.warnings.append(f"mesh {mesh.name!r} is shared by {', '.join(o.name for o in users)}: "
                                     f"all get {res}x{res} light maps")
                for o in users:
                    self.resolutions[o.name] = (res, res)
        objects = [o for o in objects if o.data in by_mesh]
        if not objects:
            raise BakeError("nothing to bake: no selected mesh has a triangle with area")
        self.objects = objects
        self.timings["choose"] = time.perf_counter() - start

        # -- unwrap each mesh once (positions scaled like its first user in the world)
        start = time.perf_counter()
        if self.atlas_size:
            self.atlas_layout = atlas_bake.unwrap_into_atlases(self, by_mesh, triangles)
        for mesh, users in (by_mesh.items() if not self.atlas_size else ()):
            tris = triangles[mesh]
            res = self.resolutions[users[0].name][0]
            scale = np.asarray(tuple(users[0].matrix_world.to_scale()), np.float64)
            try:
                result = unwrap.unwrap(tris.positions * scale, tris.triangles, res, s.padding,
                                       cache_dir=self.cache_dir, triangle_polygon=tris.polygon,
                                       max_resolution=max(s.max_resolution, res))
                uv_loop, conflicts = unwrap.loop_uvs(result.uv, tris.loops, tris.loop_count)
            except (ValueError, RuntimeError) as e:  # bad geometry, or xatlas failing to pack
                raise BakeError(f"cannot unwrap mesh {mesh.name!r} (object {users[0].name!r}): {e}") from e
            self.warnings += list(result.warnings)
            if result.resolution != res:  # the charts did not fit: the map grew until they did
                self.warnings.append(f"mesh {mesh.name!r}: its charts do not fit {res}x{res}; light map "
                                     f"{result.resolution}x{result.resolution} instead")
                for o in users:
                    self.resolutions[o.name] = (result.resolution, result.resolution)
            if conflicts:
                self.warnings.append(f"mesh {mesh.name!r}: {conflicts} polygon corners got split UVs")
            uvmaps.write_lightmap_uv(mesh, uv_loop, self.txn)
            for o in users:
                self.unwraps[o.name] = {"charts": result.chart_count, "utilization": round(result.utilization, 4),
                                        "unwrap_cached": result.from_cache, "resolution_requested": res}
        self.timings["unwrap"] = time.perf_counter() - start

        # -- extract the core scene from the evaluated depsgraph, seeing the user's materials
        # (not PDIC copies: their emission is the previous bake's light)
        start = time.perf_counter()
        showing = [o for o in self.scene.objects if writeback.is_baked_shading(o)]
        writeback.set_shading(showing, baked=False)
        for obj in showing:
            self.txn.add(lambda obj=obj: writeback.set_shading([obj], baked=True), f"show baked lighting on {obj.name}")
        depsgraph = self.context.evaluated_depsgraph_get()
        depsgraph.update()
        try:
            self.extraction = extract_scene(depsgraph, objects, uvmaps.LIGHTMAP_UV, self.resolutions)
        finally:  # objects that are not re-baked show their light maps again at once
            targets = {o.name for o in objects}
            writeback.set_shading([o for o in showing if o.name not in targets], baked=True)
        self.warnings += self.extraction.warnings  # extraction names degenerate triangles and dark scenes
        if self.atlas_layout is not None:
            self.extraction.scene = atlas_bake.window_scene(self.extraction.scene, self.atlas_layout)
        self.timings["extract"] = time.perf_counter() - start

    @property
    def texel_count(self) -> int:
        return int(sum(w * h for w, h in self.resolutions.values()))

    # ----------------------------------------------------------------- 2. compute
    def compute(self, progress: Progress | None = None) -> None:
        """Any thread; no bpy. Raises core.executor.Cancelled on cancel, SceneError on bad input."""
        from ..core import pipeline  # imported on first bake: keeps add-on registration light

        start = time.perf_counter()
        # Re-bakes of an unchanged scene reuse the photon map and cache (content-keyed, on disk
        # under the preferences' cache folder, pruned to its budget; not held in Blender's memory).
        store = bake_cache.BakeCache(self.bake_cache_dir, memory=False)
        self.result = pipeline.bake(self.extraction.scene, self.settings, progress, cache=store)
        store.prune()
        self.warnings += store.warnings  # e.g. a full cache folder: the bake went on without it
        self.timings["compute"] = time.perf_counter() - start

    # ----------------------------------------------------------------- 3. finish
    def finish(self) -> BakeReport:
        """Main thread: images, manifest, material copies. Raises BakeError after rolling back."""
        try:
            report = self._finish()
        except BaseException as e:
            self.rollback()
            if isinstance(e, (writeback.WritebackError, ValueError, KeyError, OSError)):
                raise BakeError(str(e)) from e
            raise
        self.report = report
        return report

    def _finish(self) -> BakeReport:
        start = time.perf_counter()
        plan = self.plan
        writeback.ensure_directory(plan, self.txn)
        entries, new_outputs = [], []
        atlases = atlas_bake.write_atlas_images(self, plan) if self.atlas_layout is not None else {}
        for name in self.extraction.target_objects:
            obj = bpy.data.objects.get(name)
            if obj is None:
                raise BakeError(f"object {name!r} was deleted or renamed during the bake")
            pixels = self.result.lightmaps[name]
            rebake = bool(writeback.owned_images(name) or writeback.owned_materials(name))
            temp = writeback.image_name(name) + ".pdic_new" if rebake else None
            if name in atlases:
                image, relpath, _ = atlases[name]
            else:
                image, relpath = writeback.write_image(name, pixels, plan, self.image_format, self.txn, name=temp)
            copies, warnings = writeback.build_copies(obj, image, self.txn, temporary=rebake)
            self.warnings += warnings
            new_outputs.append((obj, image, copies))
            h, w = atlases[name][2].shape[:2] if name in atlases else pixels.shape[:2]
            entries.append(dict(
                name=name, image=relpath, image_name=image.name.removesuffix(".pdic_new"), uv_map=uvmaps.LIGHTMAP_UV,
                width=int(w), height=int(h), format="OPEN_EXR", color_depth=writeback.FORMATS[self.image_format],
                color_space="Non-Color", channels="RGBA", texels=int((pixels[..., 3] > 0).sum()),
                materials=[c.name.removesuffix(".pdic_new") for c in copies], **self.unwraps.get(name, {})))
        self.timings["write_images"] = time.perf_counter() - start

        stats = dict(self.result.stats)
        stats["seconds"] = {**{f"addon_{k}": round(v, 4) for k, v in self.timings.items()},
                            **stats.get("seconds", {})}
        stats["texels"] = self.texel_count
        settings = asdict(self.settings)
        manifest_path = None
        if not plan.pack:
            manifest_path = plan.directory / core_manifest.FILENAME
            writeback.replace_file(manifest_path, lambda p: core_manifest.write_manifest(
                p, entries, stats, settings, self.warnings), self.txn)
        records_path = self._write_records(plan)
        self._remember(stats, entries, manifest_path, records_path)

        # -- commit: replace the previous outputs of these objects, show the new ones
        for obj, image, copies in new_outputs:
            writeback.remove_outputs(obj.name, keep={image, *copies})
            writeback.assign_copies(obj, copies, self.txn)
            if obj.name not in atlases:
                image.name = writeback.image_name(obj.name)
            for copy in copies:
                copy.name = copy.name.removesuffix(".pdic_new")
        if atlases:
            atlas_bake.commit_atlas_images(self)
        self.txn.commit()
        self.timings["finish"] = time.perf_counter() - start
        return BakeReport(entries, list(self.warnings), stats, plan, manifest_path, records_path)

    def _write_records(self, plan) -> Path:
        """The cache overlay's file: records p_k, n_k, E_k, R_k (zero records without indirect light)."""
        cache = self.result.cache
        K = len(cache) if cache is not None else 0
        fields = (cache.p, cache.n, cache.E, cache.R) if K else (np.zeros((0, 3)),) * 3 + (np.zeros(0),)
        path = records_file_for(plan, self.scene.name)
        origin = self.extraction.scene.origin_world
        writeback.replace_file(path, lambda p: overlay.save_records(p, *fields, origin, self.settings.a), self.txn)
        return path

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

    # ----------------------------------------------------------------- undo
    def rollback(self) -> list[str]:
        """Undo everything prepare()/finish() changed (safe to call more than once)."""
        errors = self.txn.rollback()
        return errors

    # ----------------------------------------------------------------- all at once
    def run(self, progress: Progress | None = None) -> BakeReport:
        """prepare, compute, finish on this thread (background mode, scripts)."""
        self.prepare()
        try:
            self.compute(progress)
        except BaseException as e:
            self.rollback()
            if isinstance(e, (SceneError, ValueError)):
                raise BakeError(str(e)) from e
            raise
        return self.finish()
