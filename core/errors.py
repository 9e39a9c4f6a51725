"""Typed errors raised by the core.

Operators turn these into ``self.report({'ERROR'}, str(err))``; every message
names the object, curve, point or face at fault and what is wrong with it.
"""


class FurCollideError(ValueError):
    """Base class of every error the core raises on bad input."""


class InputError(FurCollideError):
    """Curves, offsets or masks passed to the solver are malformed."""


class ColliderError(FurCollideError):
    """A collider's vertices, faces or matrix are malformed."""


class SettingsError(FurCollideError):
    """A :class:`~core.settings.Settings` field has an invalid value."""


class BackendUnavailable(ImportError):
    """The embreex ray tracer cannot be loaded on this platform."""
