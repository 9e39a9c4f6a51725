"""What every FurCollide operator shares: finding the setup, poll messages, error
reports, solving the current frame after an edit, and new hair objects."""

from __future__ import annotations

import functools

import bpy

from ..frame import scenes
from ..store import registry, report

NO_SETUP = "Active object has no FurCollide setup"


def backend_message() -> str:
    """Non-empty when the ray tracer (embreex) cannot be used here."""
    try:
        from ... import core
    except ImportError as exc:  # pragma: no cover - depends on the platform
        return f"FurCollide's core could not be loaded: {exc}"
    return "" if core.embree_available() else core.embree_error()


def active_setup(context):
    """Source object of the setup of the active object (source or output)."""
    return registry.source_of(getattr(context, "object", None))


def refuse(cls, message: str) -> bool:
    """``poll`` helper: show ``message`` as the reason and return False."""
    cls.poll_message_set(message)
    return False


class SetupOperator:
    """Mixin of the operators that act on the active object's setup.

    ``poll`` refuses with :data:`NO_SETUP` when there is no setup; in a scene the setup
    does not belong to (its hair linked into several scenes), saying which scene it
    belongs to (:func:`registry.refusal_in`): every such operator changes the setup, its
    cache or its bake; else with the reason :meth:`refusal` returns for it.
    """

    @classmethod
    def refusal(cls, context, src) -> str:
        """Why the operator cannot run on the setup of ``src`` ('' = it can)."""
        return ""

    @classmethod
    def poll(cls, context):
        src = active_setup(context)
        message = NO_SETUP if src is None else (
            registry.refusal_in(src, context.scene) or cls.refusal(context, src))
        return refuse(cls, message) if message else True


def reports_errors(execute):
    """Decorate ``execute``: an unexpected error becomes a report, not a traceback."""

    @functools.wraps(execute)
    def wrapper(self, context):
        try:
            return execute(self, context)
        except Exception as exc:  # noqa: BLE001 - reported to the artist
            self.report({"ERROR"}, f"FurCollide: {report.describe(exc)}")
            return {"CANCELLED"}

    return wrapper


def evaluate_now(context, src) -> str:
    """Solve the current frame of the setup on ``src``; returns an error or ''.

    Does nothing while the frame handler runs (an operator called from a handler
    or a bake): that run writes the frame itself. In a scene the setup does not belong
    to, its output shows the source (:func:`scenes.evaluate`).
    """
    if registry.busy():
        return ""
    try:
        scenes.evaluate(src, context.scene, context.evaluated_depsgraph_get())
    except Exception as exc:  # noqa: BLE001 - the caller reports it
        return report.describe(exc)
    return ""


def refresh(context) -> None:
    """Re-run the frame handler on the current frame (after an edit)."""
    scene = context.scene
    scene.frame_set(scene.frame_current, subframe=scene.frame_subframe)


def redraw(context) -> None:
    """Redraw the 3D views and property editors (the panel shows new state)."""
    screen = getattr(context, "screen", None)
    if screen is None:
        return
    for area in screen.areas:
        if area.type in {"VIEW_3D", "PROPERTIES"}:
            area.tag_redraw()


def new_hair_object_like(src, suffix, scene, fill):
    """New hair object "<src> <suffix>" placed, parented and linked like ``src``,
    with its materials, surface and UV map. ``fill(curves_data)`` writes the
    curves; if it raises, the half-made data is removed again."""
    hc = bpy.data.hair_curves.new(f"{src.data.name} {suffix}")
    try:
        fill(hc)
    except Exception:
        bpy.data.hair_curves.remove(hc)
        raise
    for mat in src.data.materials:
        hc.materials.append(mat)
    hc.surface = src.data.surface
    hc.surface_uv_map = src.data.surface_uv_map
    ob = bpy.data.objects.new(f"{src.name} {suffix}", hc)
    for coll in list(src.users_collection) or [scene.collection]:
        coll.objects.link(ob)
    ob.parent = src.parent
    ob.parent_type = src.parent_type
    ob.parent_bone = src.parent_bone
    ob.matrix_parent_inverse = src.matrix_parent_inverse.copy()
    ob.matrix_basis = src.matrix_basis.copy()
    return ob
