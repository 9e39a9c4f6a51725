"""FurCollide core: pure numpy + embreex, no Blender.

Public API (paper names, see README "The collision core")::

    from core import Collider, Settings, Solver, Status
"""

from .collider import Collider
from .errors import (
    BackendUnavailable,
    ColliderError,
    FurCollideError,
    InputError,
    SettingsError,
)
from .rays import embree_available, embree_error
from .settings import Settings
from .solver import Solver, Status, StepResult

__all__ = [
    "BackendUnavailable",
    "Collider",
    "ColliderError",
    "FurCollideError",
    "InputError",
    "Settings",
    "SettingsError",
    "Solver",
    "Status",
    "StepResult",
    "embree_available",
    "embree_error",
]
