"""FurCollide settings, named after the paper (snake_case).

Every field is validated on construction; an invalid value raises
:class:`~core.errors.SettingsError` (a ``ValueError``) naming the field.
Angles are in degrees, distances in world units (metres in Blender).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import asdict, dataclass, fields, replace

from .errors import SettingsError

try:  # numpy booleans count as flags, not as numbers
    from numpy import bool_ as np_bool
except ImportError:  # pragma: no cover
    np_bool = bool

MODES = ("stiff", "bend", "soft")
PINCH_RESOLUTIONS = ("stop", "growth_surface")


@dataclass(frozen=True)
class Settings:
    """Parameters of one FurCollide solve (paper section 3.2).

    Attributes
    ----------
    mode : {'stiff', 'bend', 'soft'}, default 'bend'
        *Stiff*: the whole curve rotates rigidly at its root, keeping its
        shape (short fur). *Bend*: every segment rotates about the curve's
        local axis, segment ``j`` of ``n`` by ``(j + 1) / n`` of the curve's
        angle, a uniform bend from root to tip (long fur). *Soft*: each
        colliding segment rotates about its own axis and drags the next
        ``affected_connected_cvs`` segments along with ``cv_falloff``;
        segment lengths are corrected (tight contact, cloth).
    rotation_precision : float, default 0.25
        Rotation Precision, degrees. Curves end at the smallest rotation
        that clears every collider, to within this step.
    max_angle : float, default 180
        Largest rotation (degrees) a curve may take before it counts as
        unresolvable (Stiff: the whole curve; Bend: the tip segment; Soft:
        one segment's added rotation).
    affected_connected_cvs : int, default 2
        Affected Connected CVs (Soft only): how many segments after a
        colliding segment follow its rotation.
    cv_falloff : float, default 0.5
        CV FallOff (Soft only), 0..1: the ``i``-th following segment turns
        by ``(1 - cv_falloff) ** i`` of the colliding segment's rotation.
        0 = they turn fully with it, 1 = only the colliding segment turns.
    attract_to_growth_surface : bool, default False
        Attract to Growth Surface: at the first hit, turn the curve toward
        the closest point of the growth surface from its midpoint ("patting
        down") instead of away along the collider's normal. Needs
        ``growth`` in :meth:`Solver.step`.
    shrink : bool, default False
        Shrink colliding curves while they rotate (Stiff and Bend only).
    scale_minimum : float, default 0.5
        Scale Minimum, in (0, 1]: the smallest scale a segment shrinks to.
    scale_angle : float, default 90
        Scale Angle, degrees > 0: a segment's rotation angle at which it
        reaches ``scale_minimum``; the scale ramps linearly from 1 at 0
        degrees and is clamped beyond.
    recovery_rate : float, default 0.2
        Recovery Rate, 0..1: fraction of the remaining deviation from the
        recovery target recovered per frame (1 = back at once). Recovery
        stops where the curve would collide again.
    plasticity : float, default 0
        Plasticity, 0..1: the recovery target is ``plasticity`` times the
        largest rotation reached during the contact (0 = recover fully,
        1 = keep the maximum rotation, an imprint).
    pinch_resolution : {'stop', 'growth_surface'}, default 'stop'
        What a pinched curve (root inside a closed collider) does. *Stop
        Solving* keeps the local rotation it had before the pinch. *Put to
        Growth Surface* lays it down onto the growth surface (needs
        ``growth``).
    recover_pinched : bool, default True
        Recover Pinched Fur: once out of the pinch, a curve recovers as
        usual. When False it keeps the rotation it had when it came out.
    collision_offset : float, default 0
        Distance (world units, >= 0) kept between curves and colliders. A
        collider may override it with its own ``offset``.
    threads : int or None, default None
        Ray-tracing threads (None = all CPUs). Results are bit-identical
        whatever the count.
    """

    mode: str = "bend"
    rotation_precision: float = 0.25
    max_angle: float = 180.0
    affected_connected_cvs: int = 2
    cv_falloff: float = 0.5
    attract_to_growth_surface: bool = False
    shrink: bool = False
    scale_minimum: float = 0.5
    scale_angle: float = 90.0
    recovery_rate: float = 0.2
    plasticity: float = 0.0
    pinch_resolution: str = "stop"
    recover_pinched: bool = True
    collision_offset: float = 0.0
    threads: int | None = None

    def __post_init__(self):
        def num(name, lo=None, hi=None, lo_open=False):
            v = getattr(self, name)
            if isinstance(v, (bool, np_bool)) or not isinstance(v, numbers.Real):
                raise SettingsError(f"Settings.{name} must be a number, got {v!r}")
            if not math.isfinite(v):
                raise SettingsError(f"Settings.{name} must be finite, got {v!r}")
            if lo is not None and (v < lo or (lo_open and v == lo)):
                op = ">" if lo_open else ">="
                raise SettingsError(f"Settings.{name} must be {op} {lo}, got {v!r}")
            if hi is not None and v > hi:
                raise SettingsError(f"Settings.{name} must be <= {hi}, got {v!r}")

        def flag(name):
            if not isinstance(getattr(self, name), (bool, np_bool)):
                raise SettingsError(f"Settings.{name} must be True or False")

        if self.mode not in MODES:
            raise SettingsError(f"Settings.mode must be one of {MODES}, got {self.mode!r}")
        if self.pinch_resolution not in PINCH_RESOLUTIONS:
            raise SettingsError(
                f"Settings.pinch_resolution must be one of {PINCH_RESOLUTIONS}, "
                f"got {self.pinch_resolution!r}"
            )
        num("rotation_precision", 1e-4, 45.0)
        num("max_angle", 0.0, 360.0, lo_open=True)
        if self.max_angle < self.rotation_precision:
            raise SettingsError("Settings.max_angle must be >= rotation_precision")
        if isinstance(self.affected_connected_cvs, (bool, np_bool)) or not isinstance(
            self.affected_connected_cvs, numbers.Integral
        ):
            raise SettingsError("Settings.affected_connected_cvs must be an integer")
        num("affected_connected_cvs", 0, 10_000)
        num("cv_falloff", 0.0, 1.0)
        num("scale_minimum", 0.0, 1.0, lo_open=True)
        num("scale_angle", 0.0, 360.0, lo_open=True)
        num("recovery_rate", 0.0, 1.0)
        num("plasticity", 0.0, 1.0)
        num("collision_offset", 0.0, 1e6)
        for name in ("attract_to_growth_surface", "shrink", "recover_pinched"):
            flag(name)
        if self.threads is not None:
            if isinstance(self.threads, (bool, np_bool)) or not isinstance(
                self.threads, numbers.Integral
            ):
                raise SettingsError("Settings.threads must be a positive integer or None")
            num("threads", 1, 1024)

    def replace(self, **changes) -> Settings:
        """Return a copy with ``changes`` applied (validated)."""
        unknown = set(changes) - {f.name for f in fields(self)}
        if unknown:
            raise SettingsError(f"Settings has no field {sorted(unknown)[0]!r}")
        return replace(self, **changes)

    def to_dict(self) -> dict:
        """Plain ``dict`` of every field (presets, Blender properties)."""
        return asdict(self)
