"""A source whose curves change from frame to frame, and what to say about it.

FurCollide solves the same curves frame after frame. Blender's *Generate Hair Curves* and
*Interpolate Hair Curves* scatter their curves on the Surface with a random distribution
over its faces: on a deforming Surface (an armature, shape keys) the faces change size
every frame, and so does the number of curves, unless they scatter on the Surface's *rest
position* (the group's "Surface Rest Position" switch, "Resting Surface" in Blender
5.2, with the Surface's Object > Add Rest Position on). :func:`topology_message` is the
one line the frame rules and the bake give when the source's curves changed, naming that
fix when it applies; :func:`use_rest_position` applies it (the *Use Rest Position*
button, ``furcollide.use_rest_position``).
"""

from __future__ import annotations

from ..blender import compat

#: The switch that scatters on the Surface's rest position (by Blender version:
#: :mod:`..blender.compat`, "Rest position of the Surface").
REST_INPUTS = (("Surface Rest Position", "NodeSocketBool"),
               ("Resting Surface", "NodeSocketBool"))
#: The button of :func:`topology_message`'s advice (``furcollide.use_rest_position``).
BUTTON = "Use Rest Position"


def _rest_input(mod):
    """Identifier of a nodes modifier's rest position switch, or None."""
    if mod.type != "NODES" or mod.node_group is None:
        return None
    ids = compat.group_inputs(mod.node_group)
    return next((ids[k] for k in REST_INPUTS if k in ids), None)


def _surfaces(ob, mod) -> list:
    """The Surface objects ``mod`` of hair ``ob`` scatters on (its Surface object input,
    else the hair's own Surface: Blender 5.2's groups read that)."""
    ids = compat.group_inputs(mod.node_group)
    ident = ids.get(("Surface", "NodeSocketObject"))
    surf = None
    if ident is not None:
        try:
            surf = compat.modifier_input(mod, ident)
        except (KeyError, AttributeError):
            surf = None
    surf = surf or ob.data.surface
    return [surf] if surf is not None and surf.type == "MESH" else []


def unrested(ob) -> list:
    """``[(modifier, switch identifier, surfaces)]``: the modifiers of hair ``ob`` that
    scatter curves on a Surface without its rest position (the switch off, or a Surface
    without Add Rest Position)."""
    found = []
    for mod in ob.modifiers:
        ident = _rest_input(mod)
        if ident is None or not (mod.show_viewport or mod.show_render):
            continue
        surfaces = _surfaces(ob, mod)
        off = not compat.modifier_input(mod, ident)
        if off or any(not s.add_rest_position_attribute for s in surfaces):
            found.append((mod, ident, surfaces))
    return found


def use_rest_position(ob) -> list:
    """Turn on the rest position for every modifier :func:`unrested` finds on ``ob``
    (the switch, and Add Rest Position on its Surfaces); returns what was changed, in
    words."""
    done = []
    for mod, ident, surfaces in unrested(ob):
        if not compat.modifier_input(mod, ident):
            compat.set_modifier_input(mod, ident, True)
            done.append(f"'{mod.name}' scatters on the rest position")
        for surf in surfaces:
            if not surf.add_rest_position_attribute:
                surf.add_rest_position_attribute = True
                done.append(f"'{surf.name}' has Add Rest Position on")
    if done:
        ob.update_tag()
    return done


def topology_message(ob, old, new, what="cached frames", start=1) -> str:
    """The one line a setup shows when its source's curves changed from ``old`` to
    ``new`` (``framecache.topology_key``: curves, points, ...). ``what``: "cached frames"
    (playback: the output follows the source, and the cached frames are kept), "bake" (a
    baked setup: the output keeps its last frame) or "baking" (Bake refuses the source);
    ``start``: the setup's Frame Start."""
    change = (f"'{ob.name}' changed from {old[0]} curves / {old[1]} points to {new[0]} / "
              f"{new[1]}")
    shown = {"cached frames": " The output shows the source as it is, not collided.",
             "bake": " The output keeps its last frame."}.get(what, "")
    found = unrested(ob)
    if found:
        names = ", ".join(f"'{m.name}'" for m, _i, _s in found)
        return (f"{change}: {names} scatter{'s' if len(found) == 1 else ''} its curves on "
                "the deforming Surface, so their number changes every frame. Press "
                f"{BUTTON} (it turns on the modifier's Surface Rest Position and the "
                f"Surface's Add Rest Position), then play from frame {start}.{shown}")
    if what != "cached frames":
        return f"{change}: the bake was made for the old curves.{shown} Press Free Bake, " \
            "then Bake."
    return (f"{change}: the output shows the source as it is, not collided, and the "
            f"cached frames are kept. To collide the new curves, press Reset Cache and play "
            f"from frame {start}.")
