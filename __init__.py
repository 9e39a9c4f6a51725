"""FurCollide for Blender: register/unregister only.

All collision math lives in :mod:`.core` (pure numpy + embreex); the Blender
glue lives in :mod:`.operators` and :mod:`.ui`.
"""

ADDON_ID = __package__


def register():
    from . import operators, ui

    operators.register()
    ui.register()


def unregister():
    from . import operators, ui

    ui.unregister()
    operators.unregister()
