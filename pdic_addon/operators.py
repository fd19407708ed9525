"""Operators: bake, clear, toggle shading. Docstrings are the tooltips.

``pdic.bake`` runs a :class:`.job.BakeJob`: synchronously in background mode
(or when called from a script with ``execute``), otherwise as a modal
operator whose worker thread runs the pure-core compute step while a timer
reports progress; Esc cancels, and a cancelled or failed bake leaves the file
as it was.
"""
from __future__ import annotations

import threading
import traceback

import bpy
from bpy.props import EnumProperty

from ..core.executor import Cancelled, Progress
from ..core.scene import SceneError
from . import writeback
from .job import BakeError, BakeJob
from .properties import to_settings

SCOPE_ITEMS = (
    ("ALL", "All", "Every bakeable mesh in the view layer"),
    ("SELECTED", "Selected", "Only the selected meshes"),
)


def _settings(context):
    props = getattr(context.scene, "pdic", None)
    if props is None:
        from ..core.settings import BakeSettings
        return BakeSettings()
    return to_settings(props)


def _internal(error) -> str:
    return (f"PDIC internal error ({type(error).__name__}: {error}); the file was left unchanged, "
            f"see the console for the traceback")


def _summary(report) -> str:
    names = ", ".join(e["name"] for e in report.objects)
    where = "packed into the .blend" if report.output.pack else str(report.output.directory)
    return f"PDIC: baked {len(report.objects)} light map(s) ({names}) -> {where}"


class PDIC_OT_bake(bpy.types.Operator):
    """Bake light maps with the photon-driven irradiance cache (Esc cancels; the file stays unchanged)"""

    bl_idname = "pdic.bake"
    bl_label = "Bake Light Maps"
    bl_options = {"REGISTER", "UNDO"}

    scope: EnumProperty(name="Objects", items=SCOPE_ITEMS, default="ALL")

    _running = False  # one bake at a time (class-wide)

    @classmethod
    def poll(cls, context):
        if cls._running:
            cls.poll_message_set("a PDIC bake is already running")
            return False
        return context.scene is not None

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
        return {"FINISHED"}

    # ------------------------------------------------------------ modal
    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        try:
            self.job = self._make_job(context)
            self.job.prepare()
        except (BakeError, SceneError, ValueError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        self._state = {"stage": "Starting", "fraction": 0.0, "eta": None}
        self.progress = Progress(self._on_progress)
        self.error = None
        self.thread = threading.Thread(target=self._compute, name="pdic-bake", daemon=True)
        type(self)._running = True
        wm = context.window_manager
        self.timer = wm.event_timer_add(0.2, window=context.window)
        wm.progress_begin(0, 1000)
        wm.modal_handler_add(self)
        self.thread.start()
        return {"RUNNING_MODAL"}

    def _on_progress(self, stage, fraction, eta):  # worker thread: only plain data here
        self._state = {"stage": stage, "fraction": fraction, "eta": eta}

    def _compute(self):
        try:
            self.job.compute(self.progress)
        except BaseException as e:  # handed to the main thread
            self.error = e

    def _set_status(self, context, text):
        if context.workspace is not None:
            context.workspace.status_text_set(text)
        if context.area is not None:
            context.area.header_text_set(text)

    def _end(self, context):
        wm = context.window_manager
        wm.event_timer_remove(self.timer)
        wm.progress_end()
        self._set_status(context, None)
        type(self)._running = False

    def modal(self, context, event):
        if event.type == "ESC" and event.value == "PRESS":
            self.progress.cancel()
            self._set_status(context, "PDIC: cancelling...")
            return {"RUNNING_MODAL"}
        if event.type != "TIMER" or event.timer is not self.timer:
            return {"PASS_THROUGH"}
        if self.thread.is_alive():
            s = self._state
            eta = f", {s['eta']:.0f} s left" if s["eta"] is not None else ""
            context.window_manager.progress_update(int(1000 * s["fraction"]))
            self._set_status(context, f"PDIC: {s['stage']} {100 * s['fraction']:.0f}%{eta} (Esc to cancel)")
            return {"PASS_THROUGH"}
        self._end(context)
        if self.error is not None:
            self.job.rollback()
            if isinstance(self.error, Cancelled):
                self.report({"WARNING"}, "PDIC: bake cancelled; nothing was changed")
            elif isinstance(self.error, (SceneError, ValueError)):
                self.report({"ERROR"}, f"PDIC: {self.error}")
            else:
                traceback.print_exception(self.error)
                self.report({"ERROR"}, _internal(self.error))
            return {"CANCELLED"}
        try:
            report = self.job.finish()
        except (BakeError, SceneError, ValueError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        except Exception as e:
            traceback.print_exc()
            self.report({"ERROR"}, _internal(e))
            return {"CANCELLED"}
        self._report_done(report)
        return {"FINISHED"}

    def cancel(self, context):  # Blender closes the window / file during the bake
        self.progress.cancel()
        self.thread.join()
        self.job.rollback()
        self._end(context)


class PDIC_OT_clear(bpy.types.Operator):
    """Remove everything PDIC added (light-map UV maps, images, material copies) and restore the materials"""

    bl_idname = "pdic.clear"
    bl_label = "Clear Light Maps"
    bl_options = {"REGISTER", "UNDO"}

    scope: EnumProperty(name="Objects", items=(
        ("ALL", "Whole File", "Everything PDIC added anywhere in the file"),
        ("SELECTED", "Selected", "Only the selected objects' light maps"),
    ), default="ALL")

    def execute(self, context):
        if self.scope == "SELECTED":
            counts = writeback.clear(list(context.selected_objects))
        else:
            counts = writeback.clear(None)
        if not any(counts.values()):
            self.report({"INFO"}, "PDIC: nothing to clear")
        else:
            self.report({"INFO"}, "PDIC: removed " + ", ".join(f"{v} {k.replace('_', ' ')}" for k, v in counts.items()))
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
    ), default="TOGGLE")

    def execute(self, context):
        objects = [o for o in context.scene.objects if writeback.owned_materials(o.name)]
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


classes = (PDIC_OT_bake, PDIC_OT_clear, PDIC_OT_toggle_shading)


def register():
    for cls in classes:
        bpy.utils.register_class(cls)


def unregister():
    for cls in reversed(classes):
        bpy.utils.unregister_class(cls)
