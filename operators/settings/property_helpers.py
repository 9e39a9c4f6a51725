"""How the setup's properties are declared: their update callbacks and factories.

Every property that changes the result drops the playback cache (as Blender's point
cache does; only a shorter frame range keeps the frames inside it) through its
``update=`` callback (:func:`invalidation.invalidate`). Like the frame
handler, the callbacks never raise (a failure is one console line; the next frame
re-checks everything). The factories give the solver settings their few shapes (a
toggle, a 0..1 factor, a distance...), leaving the name, default and tooltip to the call.
"""

import functools

from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, StringProperty

from ..blender import bridge
from ..frame import children, output
from ..frame.colliders import instanced_collection
from ..store import invalidation, playback, registry, report
from . import maps

# ------------------------------------------------------------------ updates
# Update callbacks run inside Blender's UI: like the frame handler, they never
# raise (a failure is one console line; the next frame re-checks everything).


def never_raises(update):
    @functools.wraps(update)
    def wrapper(self, context):
        try:
            update(self, context)
        except Exception as exc:  # noqa: BLE001
            print(f"FurCollide: {update.__name__.strip('_')} failed: {report.describe(exc)}")

    return wrapper


@never_raises
def update_settings(self, context):
    invalidation.invalidate(self.id_data, context.scene, reason="the settings changed",
                            values=True)


def update_colliders_because(reason):
    """An update for the colliders' properties: drops the cached frames from the first
    one it changes (every one when the value is the same at every frame) and forgets
    the core Colliders."""

    @never_raises
    def update(self, context):
        invalidation.invalidate(self.id_data, context.scene, reason=reason, colliders=True,
                                values=True)

    return update


update_colliders = update_colliders_because("the colliders changed")
update_collider_options = update_colliders_because(
    "a collider's Double Sided or Collision Offset changed")


@never_raises
def update_range(self, context):
    ob = self.id_data
    s = ob.furcollide
    if s.frame_end < s.frame_start:
        s.frame_end = s.frame_start
        return
    rt = registry.get_runtime(ob, create=False)
    if rt is not None and rt.cache.memory.start == s.frame_start:
        # Only the end moved: frames inside the new range stay valid.
        invalidation.invalidate(ob, context.scene, reason="the frame range changed",
                                from_frame=s.frame_end)
    else:
        invalidation.invalidate(ob, context.scene, reason="the frame range changed",
                                from_frame=s.frame_start - 1)


def update_every_frame(reason):
    """An update that drops every cached frame: for changes of every frame's input
    (Fur Attach, motion before collision) or output (motion after collision). The
    memory cache stores only the curves that differ from the input, so earlier frames
    would mix old results with the new input."""

    @never_raises
    def update(self, context):
        ob = self.id_data
        invalidation.invalidate(ob, context.scene, reason=reason,
                                from_frame=ob.furcollide.frame_start - 1)

    return update


update_attach = update_every_frame("Fur Attach changed")


@never_raises
def update_motion(self, context):
    """A wind, jiggle, Region of Influence or distance setting changed: the cached frames
    from the first one it changes go. (The memory cache stores results against the
    input before motion, so the frames before it still hold.)"""
    invalidation.invalidate(self.id_data, context.scene,
                            reason="the motion settings changed", values=True)


@never_raises
def update_memory_limit(self, context):
    rt = registry.get_runtime(self.id_data, create=False)
    if rt is not None:
        playback.set_limit(rt, self.memory_limit)


@never_raises
def update_show_result(self, context):
    output.apply_visibility(self.id_data)
    src = registry.source_of(self.id_data)
    if src is not None:
        children.apply_visibility(src)


def poll_collider(self, ob):
    return bridge.is_collider_type(ob) or instanced_collection(ob) is not None


def poll_hair(self, ob):
    return ob.type == "CURVES"


@never_raises
def update_groom(self, context):
    invalidation.refresh_groom(self.id_data)


@never_raises
def update_children(self, context):
    """Clear Children: off removes the children output (the output renders its own
    stack again); on makes it on the next frame shown (now, in the UI)."""
    src = registry.source_of(self.id_data)
    if src is None:
        return
    if not self.use_children:
        children.remove_children_output(src)
    invalidation.schedule_refresh(src.name)


@never_raises
def update_children_viewport(self, context):
    src = registry.source_of(self.id_data)
    if src is not None:
        invalidation.schedule_refresh(src.name)


# ------------------------------------------------------ property factories
# The solver settings share a few shapes; each factory fixes the shape and
# leaves the name, default and the artist-facing tooltip to the call. (The angles are
# :func:`.angles.angle`.)


def toggle(name, default, description, update=update_settings, animatable=True):
    kw = {} if animatable else {"options": NOT_ANIMATABLE}
    return BoolProperty(name=name, default=default, update=update, description=description,
                        **kw)


def factor(name, default, description):
    """A 0..1 slider."""
    return FloatProperty(
        name=name, default=default, min=0.0, max=1.0, subtype="FACTOR",
        update=update_settings, description=description,
    )


def offset_property(description, update):
    """A collision offset (world distance)."""
    return FloatProperty(
        name="Offset", default=0.0, min=0.0, soft_max=0.1, subtype="DISTANCE",
        unit="LENGTH", update=update, description=description,
    )


#: Options of a setting that cannot change mid-shot: Blender refuses to key or drive it
#: ("property ... not animatable"); its tooltip says why (:func:`fixed`).
NOT_ANIMATABLE = set()


def fixed(description, why):
    """The tooltip of a setting that cannot be keyed: ``description`` and ``why``."""
    return f"{description}. It cannot be keyed or driven: {why}"


def choice(name, items, default, description, animatable=True):
    """One of a few named behaviours (``items``: identifier, label, tooltip)."""
    kw = {} if animatable else {"options": NOT_ANIMATABLE}
    return EnumProperty(
        name=name, items=items, default=default, update=update_settings, description=description,
        **kw,
    )


def map_property(setting):
    """The name of a float attribute that maps ``setting`` per curve (:mod:`.maps`)."""

    def search(self, context, edit_text):
        return maps.suggestions(self.id_data, context, edit_text)

    return StringProperty(
        name=f"{setting} Map", default="", update=update_settings, search=search,
        description=f"Float attribute of the evaluated hair (per curve, or per point: read "
        f"at the root) that scales {setting} curve by curve: each curve uses {setting} "
        "times its value, clamped to the setting's range. Paint it on the growth surface "
        "and store it on the hair with Geometry Nodes. Empty: the same for every curve",
    )


def hidden(prop, name, default):
    """Internal bookkeeping, never drawn."""
    return prop(name=name, default=default, options={"HIDDEN"},
                description=f"{name} (set by FurCollide, not meant to be edited)")


def stat(name, key, description, prop=IntProperty, **kw):
    """A read-only statistic of the last frame, served by the runtime registry."""
    default = 0.0 if prop is FloatProperty else 0

    def get(self):
        return report.stats_for(self.id_data).get(key, default)

    return prop(name=name, get=get, description=description, **kw)
