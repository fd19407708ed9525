"""Operators: bake, clear, toggle shading. Docstrings are the tooltips.

``pdic.bake`` runs a :class:`.job.BakeJob`: synchronously in background mode
(or when called from a script with ``execute``), otherwise as a modal
operator whose worker thread runs the pure-core compute step while a timer
reports progress; Esc cancels, and a cancelled or failed bake leaves the file
as it was.

While a modal bake runs, the job holds references into the current file, so
undo (Ctrl+Z is swallowed with a message) and loading a file first abort it:
the undo_pre/redo_pre/load_pre handler stops the worker and rolls the job back
while the data it touched still exists. A finished bake is one undo step;
files written to disk are not part of Blender's undo (see docs/settings.md).
"""
from __future__ import annotations

import traceback

import bpy
from bpy.app.handlers import persistent
from bpy.props import EnumProperty

from ..core.executor import Cancelled, Progress
from ..core.scene import SceneError
from . import overlay, preferences, writeback
from .job import BakeError, BakeJob, JobRunner
from .properties import to_settings

SCOPE_ITEMS = (
    ("ALL", "All", "Every bakeable mesh in the view layer"),
    ("SELECTED", "Selected", "Only the selected meshes"),
)


def _settings(context):
    """The frozen core settings: ``scene.pdic`` plus the thread count from the add-on preferences."""
    threads = preferences.threads(preferences.addon_preferences(context))
    props = getattr(context.scene, "pdic", None)
    if props is None:
        from ..core.settings import BakeSettings
        return BakeSettings(threads=threads)
    return to_settings(props, threads=threads)


def _internal(error) -> str:
    return (f"PDIC internal error ({type(error).__name__}: {error}); the file was left unchanged, "
            f"see the console for the traceback")


def _summary(report) -> str:
    names = ", ".join(e["name"] for e in report.objects)
    where = "packed into the .blend" if report.output.pack else str(report.output.directory)
    seconds = report.stats.get("seconds_total")
    took = f" in {seconds:.1f} s" if isinstance(seconds, (int, float)) else ""
    return f"PDIC: baked {len(report.objects)} light map(s) ({names}){took} -> {where}"


def status_text(stage: str, fraction: float, eta: float | None) -> str:
    """The progress line shown in the header and status bar, e.g. ``PDIC: Pass 1: tracing photons 42%, 12 s left``."""
    left = f", {eta:.0f} s left" if eta is not None else ""
    return f"PDIC: {stage} {100 * fraction:.0f}%{left} (Esc to cancel)"


def _is_undo_key(event) -> bool:
    return event.type == "Z" and event.value == "PRESS" and (event.ctrl or event.oskey)


class PDIC_OT_bake(bpy.types.Operator):
    """Bake light maps with the photon-driven irradiance cache. Blender stays usable while it runs; \
Esc or Cancel stops it and leaves the file unchanged"""

    bl_idname = "pdic.bake"
    bl_label = "Bake Light Maps"
    bl_options = {"REGISTER", "UNDO"}

    scope: EnumProperty(name="Objects", items=SCOPE_ITEMS, default="ALL",
                        description="Which objects get light maps")

    # One bake at a time. The running modal operator, for the panel (progress, Cancel)
    # and the undo/load handlers; plain class state, reset in _end().
    _active = None
    _running = False

    @classmethod
    def poll(cls, context):
        if cls._running:
            cls.poll_message_set("a PDIC bake is already running")
            return False
        return context.scene is not None

    @classmethod
    def description(cls, context, properties):
        if properties.scope == "SELECTED":
            return ("Bake light maps for the selected meshes only (the rest still cast shadows and bounce "
                    "light). Esc or Cancel stops the bake and leaves the file unchanged")
        return cls.__doc__

    @classmethod
    def running(cls):
        """The modal bake in progress, or None."""
        return cls._active

    def _make_job(self, context) -> BakeJob:
        return BakeJob(context, _settings(context), selected_only=self.scope == "SELECTED")

    def _report_done(self, report):
        for w in report.warnings:
            self.report({"WARNING"}, w)
        self.report({"INFO"}, _summary(report))

    # ------------------------------------------------------------ synchronous
    def execute(self, context):
        try:
            job = self._make_job(context)
            report = job.run()
        except (BakeError, SceneError, ValueError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        except Exception as e:  # a bug: the job has rolled back; say so instead of a bare traceback
            traceback.print_exc()
            self.report({"ERROR"}, _internal(e))
            return {"CANCELLED"}
        self._report_done(report)
        overlay.tag_redraw(context)
        return {"FINISHED"}

    # ------------------------------------------------------------ modal
    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        self.state = {"stage": "Starting", "fraction": 0.0, "eta": None}
        self.progress = Progress(self._on_progress)
        try:
            self.job = self._make_job(context)
            self.runner = JobRunner(self.job, self.progress)
            self.runner.advance_to_worker()  # the choose step: errors show at once, before any wait
        except (BakeError, SceneError, ValueError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        except Exception as e:  # a bug: the step has rolled back
            traceback.print_exc()
            self.report({"ERROR"}, _internal(e))
            return {"CANCELLED"}
        self.aborted = False
        type(self)._running = True
        type(self)._active = self
        wm = context.window_manager
        self.timer = wm.event_timer_add(0.2, window=context.window)
        wm.progress_begin(0, 1000)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def _on_progress(self, stage, fraction, eta):  # worker thread: only plain data here
        self.state = {"stage": stage, "fraction": fraction, "eta": eta}

    def request_cancel(self):
        """Ask the worker to stop (any thread); it raises Cancelled at its next chunk (< ~1 s)."""
        self.progress.cancel()

    def abort(self):
        """Main thread, before undo or loading a file: stop now and undo the bake's changes while
        the data it touched still exists; the modal step then just ends."""
        self.progress.cancel()
        runner = getattr(self, "runner", None)
        thread = runner.thread if runner is not None else self.thread
        if thread is not None:
            thread.join()
        self.job.rollback()
        self.aborted = True

    def _set_status(self, context, text):
        if context.workspace is not None:
            context.workspace.status_text_set(text)
        if context.area is not None:
            context.area.header_text_set(text)

    def _end(self, context):
        wm = context.window_manager
        if self.timer is not None:
            wm.event_timer_remove(self.timer)
            self.timer = None
        wm.progress_end()
        self._set_status(context, None)
        type(self)._running = False
        type(self)._active = None
        _redraw_sidebars(context)

    def modal(self, context, event):
        if self.aborted:  # undo or file load stopped the bake (see _abort_running_bake)
            self._end(context)
            self.report({"WARNING"}, "PDIC: bake stopped by undo or file load; nothing was changed")
            return {"CANCELLED"}
        if event.type == "ESC" and event.value == "PRESS":
            self.request_cancel()
            self._set_status(context, "PDIC: cancelling...")
            return {"RUNNING_MODAL"}
        if _is_undo_key(event):  # the bake holds references into the current undo state
            self.report({"WARNING"}, "PDIC: undo is not available while baking (Esc cancels the bake)")
            return {"RUNNING_MODAL"}
        if event.type != "TIMER" or event.timer is not self.timer:
            return {"PASS_THROUGH"}
        if not self.runner.advance():
            s = self.state
            context.window_manager.progress_update(int(1000 * s["fraction"]))
            if not self.progress.cancel_requested.is_set():
                self._set_status(context, status_text(s["stage"], s["fraction"], s["eta"]))
            _redraw_sidebars(context)
            return {"PASS_THROUGH"}
        self._end(context)
        return self._conclude(context)

    def _conclude(self, context):
        """Main thread, the runner is done: report the failure (already rolled back) or the results."""
        error = self.runner.error
        if error is None:
            self._report_done(self.job.report)
            overlay.tag_redraw(context)
            return {"FINISHED"}
        if isinstance(error, Cancelled):
            self.report({"WARNING"}, "PDIC: bake cancelled; nothing was changed")
        elif isinstance(error, (BakeError, SceneError, ValueError)):
            self.report({"ERROR"}, f"PDIC: {error}" if not isinstance(error, BakeError) else str(error))
        else:
            traceback.print_exception(error)
            self.report({"ERROR"}, _internal(error))
        return {"CANCELLED"}

    def cancel(self, context):  # Blender closes the window / file during the bake
        if not self.aborted:
            self.abort()
        self._end(context)


class PDIC_OT_cancel_bake(bpy.types.Operator):
    """Stop the running light-map bake; the file stays as it was before the bake"""

    bl_idname = "pdic.cancel_bake"
    bl_label = "Cancel Bake"
    bl_options = {"INTERNAL"}

    @classmethod
    def poll(cls, context):
        return PDIC_OT_bake.running() is not None

    def execute(self, context):
        PDIC_OT_bake.running().request_cancel()
        return {"FINISHED"}


def _redraw_sidebars(context):
    """Redraw 3D-viewport sidebars (the panel shows the bake's progress)."""
    wm = getattr(context, "window_manager", None)
    for window in (wm.windows if wm is not None else ()):
        for area in (window.screen.areas if window.screen is not None else ()):
            if area.type == "VIEW_3D":
                for region in area.regions:
                    if region.type == "UI":
                        region.tag_redraw()


@persistent
def _abort_running_bake(*_args):
    """undo_pre / redo_pre / load_pre: a running bake is stopped and rolled back first."""
    running = PDIC_OT_bake.running()
    if running is not None and not running.aborted:
        running.abort()


HANDLERS = ("undo_pre", "redo_pre", "load_pre")


class PDIC_OT_clear(bpy.types.Operator):
    """Remove everything PDIC added (light-map UV maps, images, material copies) and restore the materials"""

    bl_idname = "pdic.clear"
    bl_label = "Clear Light Maps"
    bl_options = {"REGISTER", "UNDO"}

    scope: EnumProperty(name="Objects", items=(
        ("ALL", "Whole File", "Everything PDIC added anywhere in the file"),
        ("SELECTED", "Selected", "Only the selected objects' light maps"),
    ), default="ALL", description="Whose light maps to remove (files on disk are kept)")

    def execute(self, context):
        if self.scope == "SELECTED":
            counts = writeback.clear(list(context.selected_objects))
        else:
            counts = writeback.clear(None)
            for scene in bpy.data.scenes:  # the last bake's statistics and overlay go with it
                props = getattr(scene, "pdic", None)
                if props is not None and scene.library is None:
                    props.last_stats = props.manifest_file = props.records_file = ""
            overlay.tag_redraw(context)
        kept = counts.pop("kept_edited", 0)
        if kept:
            self.report({"WARNING"}, f"PDIC: kept {kept} edited baked-lighting material(s) as '... (edited)' "
                                     f"materials (your edits; delete them if not needed)")
        if not any(counts.values()):
            self.report({"INFO"}, "PDIC: nothing to clear")
        else:
            removed = ", ".join(f"{v} {k.replace('_', ' ')}" for k, v in counts.items())
            self.report({"INFO"}, "PDIC: removed " + removed)
        return {"FINISHED"}


class PDIC_OT_toggle_shading(bpy.types.Operator):
    """Switch between the baked lighting and the objects' original materials"""

    bl_idname = "pdic.toggle_shading"
    bl_label = "Toggle Baked Lighting"
    bl_options = {"REGISTER", "UNDO"}

    mode: EnumProperty(name="Show", items=(
        ("TOGGLE", "Toggle", "Switch to whichever is not shown"),
        ("BAKED", "Baked Lighting", "Show the light maps"),
        ("ORIGINAL", "Original", "Show the original materials"),
    ), default="TOGGLE", description="Which shading to show on the baked objects")

    def execute(self, context):
        objects = [o for o in context.scene.objects if writeback.owned_materials(o)]
        if not objects:
            self.report({"WARNING"}, "PDIC: no baked light maps in this scene (bake first)")
            return {"CANCELLED"}
        baked = {"BAKED": True, "ORIGINAL": False}.get(self.mode)
        if baked is None:
            baked = not any(writeback.is_baked_shading(o) for o in objects)
        switched = writeback.set_shading(objects, baked)
        self.report({"INFO"}, f"PDIC: {'baked lighting' if baked else 'original materials'} "
                              f"({switched} slot(s) switched)")
        return {"FINISHED"}


classes = (PDIC_OT_bake, PDIC_OT_cancel_bake, PDIC_OT_clear, PDIC_OT_toggle_shading)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)
    for name in HANDLERS:
        getattr(bpy.app.handlers, name).append(_abort_running_bake)


def unregister():
    for name in HANDLERS:
        handlers = getattr(bpy.app.handlers, name)
        while _abort_running_bake in handlers:
            handlers.remove(_abort_running_bake)
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
