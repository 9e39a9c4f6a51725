"""FurCollide for Blender: hair, fur and grass curves collide with meshes without a
physics simulation (SIGGRAPH 2017 "FurCollide"). This module only registers and
unregisters the extension.

All collision math lives in :mod:`.core` (pure numpy + embreex, no Blender); the
Blender glue lives in :mod:`.operators` (settings, operators, the frame handler) and
:mod:`.ui` (the sidebar panel). README "How the code is organised" maps every module.
"""

ADDON_ID = __package__


def _backend_problem() -> str:
    """Why the ray tracer cannot run here ('' when it can)."""
    try:
        from . import core
    except Exception as exc:  # noqa: BLE001 - reported, never raised
        return f"FurCollide could not load its core: {type(exc).__name__}: {exc}"
    return "" if core.embree_available() else core.embree_error()


def register():
    from . import operators, ui

    operators.register()
    ui.register()
    problem = _backend_problem()
    if problem:
        # Registered anyway: the panel shows the message and the operators'
        # poll explains why they are unavailable.
        print(f"FurCollide: {problem}")


def unregister():
    from . import operators, ui

    ui.unregister()
    operators.unregister()
