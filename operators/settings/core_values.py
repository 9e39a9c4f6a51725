"""The setup's settings as :class:`core.Settings` takes them.

Blender shows and keys the angles in radians and spells its choices in upper case, as
every Blender property; the core takes degrees and lower case (``Settings(mode="bend",
max_angle=120.0)``). :func:`core_value` reads a setting the core's way (the angles as
stored, in degrees: :mod:`.angles`); :func:`set_core_values` sets settings from the
core's names and values (scripts that share one set of settings with the core). Records
of what a frame was solved from keep the core's values (:mod:`.keyed`), as every version
recorded them.
"""

from __future__ import annotations

import math

from . import angles

#: The choices the core spells in lower case (``core.Settings(mode="bend")``); Blender's
#: identifiers are upper case, as every Blender enum's ("BEND", "GROWTH_SURFACE").
CORE_CHOICES = ("mode", "pinch_resolution")


def core_value(s, name):
    """Setting ``name`` of the setup properties ``s`` as :class:`core.Settings` takes it:
    an angle in degrees exactly as stored (:func:`angles.degrees`), a choice in lower
    case, anything else as it is."""
    if name in angles.ANGLES:
        return angles.degrees(s, name)
    value = getattr(s, name)
    return value.lower() if name in CORE_CHOICES else value


def set_core_values(s, **values) -> None:
    """Set the setup properties ``s`` from :class:`core.Settings` names and values (angles
    in degrees, choices as the core spells them: ``set_core_values(s, mode="bend",
    max_angle=120.0)``), as the panel would set them (each property's update runs).
    For scripts that share their settings with the core (``scripts/demo.py``)."""
    for name, value in values.items():
        if name in angles.ANGLES:
            value = math.radians(value)
        elif name in CORE_CHOICES:
            value = value.upper()
        setattr(s, name, value)


