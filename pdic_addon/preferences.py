"""Add-on preferences (Edit > Preferences > Add-ons > PDIC): thread count, cache folder, Dask scheduler.

These are per-user, per-machine choices, so they live in the preferences,
not in the .blend. The preferences class must be registered under the
add-on's *root* package name: ``bl_ext.<repository>.pdic`` when installed
as an extension, ``pdic`` when the tests import the checkout. That is the
package of this module minus its last component (``pdic_addon``).

:func:`addon_preferences` returns None when the add-on's classes are
registered without Blender having enabled the add-on (scripts that call
``pdic_addon.register()`` directly); the helpers then fall back to the
defaults (all cores, the extension's user folder).
"""
from __future__ import annotations

import importlib.util
import os
import tempfile
from pathlib import Path

import bpy
from bpy.props import IntProperty, StringProperty

ROOT_PACKAGE = __package__.rpartition(".")[0]
"""``bl_idname`` of the preferences: the extension's package (``bl_ext.user_default.pdic`` or ``pdic``)."""


class PDIC_AddonPreferences(bpy.types.AddonPreferences):
    """PDIC preferences: how many threads a bake uses and where reusable data is cached."""

    bl_idname = ROOT_PACKAGE

    threads: IntProperty(
        name="Threads", default=0, min=0, max=1024,
        description="Worker threads a bake uses (0 = all cores). Lower it to keep the machine responsive "
                    "while baking; results do not depend on it")
    cache_folder: StringProperty(
        name="Cache Folder", default="", subtype="DIR_PATH",
        description="Folder for data reused between bakes (UV unwraps keyed on the mesh, the records of "
                    "bakes of unsaved files). Empty = the extension's user folder")
    scheduler: StringProperty(
        name="Dask Scheduler", default="",
        description="Run the heavy stages on a Dask cluster: tcp://host:port of a running 'dask scheduler', "
                    "or local:N for N worker processes on this machine. Empty = threads on this machine. "
                    "Needs dask and distributed in Blender's Python; light maps are the same either way")

    def draw(self, context):
        draw_preferences(self.layout, self)


def draw_preferences(layout, prefs) -> None:
    """Threads and cache folder, and the cache folder actually in use."""
    layout.use_property_split = True
    layout.prop(prefs, "threads")
    layout.prop(prefs, "cache_folder")
    layout.label(text=f"In use: {cache_dir(prefs)}", icon="FILE_FOLDER")
    layout.prop(prefs, "scheduler")
    if prefs.scheduler.strip() and not dask_installed():
        from ..core.dask_executor import install_hint

        layout.label(text=f"Dask is not installed: {install_hint()}", icon="ERROR")


def dask_installed() -> bool:
    return importlib.util.find_spec("distributed") is not None


def addon_preferences(context=None):
    """The registered :class:`PDIC_AddonPreferences`, or None if Blender has not enabled the add-on."""
    context = context or bpy.context
    prefs = getattr(context, "preferences", None)
    addon = prefs.addons.get(ROOT_PACKAGE) if prefs is not None else None
    return addon.preferences if addon is not None else None


def threads(prefs=None) -> int:
    """Worker threads for the executor: the preference, 0 (= all cores) without one."""
    prefs = prefs if prefs is not None else addon_preferences()
    return int(prefs.threads) if prefs is not None else 0


def scheduler(prefs=None) -> str:
    """The Dask scheduler address of the preferences, "" (the thread pool) without one."""
    prefs = prefs if prefs is not None else addon_preferences()
    return prefs.scheduler.strip() if prefs is not None else ""


def default_cache_dir() -> Path:
    """``$PDIC_CACHE_DIR`` if set, else the extension's user folder (``.../extensions/.user/<repo>/pdic/``),
    else ``<tmp>/pdic_cache`` (scripts and tests running from a checkout)."""
    if os.environ.get("PDIC_CACHE_DIR"):
        return Path(os.environ["PDIC_CACHE_DIR"])
    try:
        return Path(bpy.utils.extension_path_user(ROOT_PACKAGE, create=True))
    except (ValueError, RuntimeError, AttributeError):  # not installed as an extension (tests, scripts)
        return Path(tempfile.gettempdir()) / "pdic_cache"


def cache_dir(prefs=None, sub: str = "") -> Path:
    """The cache folder (preference or default), with an optional sub-folder ``sub``; not created."""
    prefs = prefs if prefs is not None else addon_preferences()
    folder = (prefs.cache_folder.strip() if prefs is not None else "")
    base = Path(bpy.path.abspath(folder)) if folder else default_cache_dir()
    base = Path(os.path.expanduser(str(base)))
    return base / sub if sub else base


classes = (PDIC_AddonPreferences,)


register, unregister = bpy.utils.register_classes_factory(classes)
