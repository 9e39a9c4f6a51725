"""FurCollide settings, named after the paper (snake_case).

Every field is validated on construction; an invalid value raises
:class:`~core.errors.SettingsError` (a ``ValueError``) naming the field.
Angles are in degrees, distances in world units (metres in Blender).

Parameter maps: the fields in :data:`PER_CURVE` take either one number for
every curve or a ``(C,)`` array, one value per curve (curve ``i`` of the
solver's layout). An array is validated element by element (the message names
the field and the first bad curve) and stored as a read-only float64 copy;
its length is checked against the curve count where the curves are known
(:class:`core.Solver`: construction, ``solver.settings = ...``, every step).
A uniform array gives the same result as the plain number, bit for bit.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import asdict, dataclass, fields, replace

import numpy as np

from . import tolerances as tol
from .errors import SettingsError

np_bool = np.bool_  # numpy booleans count as flags, not as numbers

MODES = ("stiff", "bend", "soft")
#: The largest distance (world units) a collision offset or clearance margin takes.
MAX_DISTANCE = 1e6
PINCH_RESOLUTIONS = ("stop", "growth_surface")

#: The fields that take a parameter map: one number, or a (C,) array with one
#: value per curve.
PER_CURVE = ("max_angle", "scale_minimum", "recovery_rate", "plasticity",
             "collision_offset", "clearance_margin")


@dataclass(frozen=True, eq=False)
class Settings:
    """Parameters of one FurCollide solve (paper section 3.2).

    Fields marked *per curve* take a number or a ``(C,)`` array of numbers,
    one per curve (a parameter map, e.g. painted weights times the setting):
    each element is validated as the number would be, and the array is kept
    as a read-only float64 copy. Settings compare (``==``) and hash by value,
    arrays included.

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
    max_angle : float or (C,) array, default 180, per curve
        Largest rotation (degrees, in (0, 360] and >= ``rotation_precision``)
        a curve may take before it counts as unresolvable (Stiff: the whole
        curve; Bend: the tip segment; Soft: one segment's added rotation).
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
    follow_collider_motion : bool, default False
        Follow Collider Motion: at the first hit, turn the curve so that its
        tip moves the way the collider moves at the contact point (a hand
        stroking fur, a ball rolling through grass): the direction is the
        collider's velocity there (from its previous placement,
        :attr:`Collider.previous`), made perpendicular to the hit segment.
        The axis is then kept until the curve has recovered, as any other.
        Where the collider does not move at the contact (that velocity below
        ``tolerances.FOLLOW_SPEED_REL`` of the curve's length per step, or no
        previous placement known), the curve takes the paper's direction:
        toward the growth surface with ``attract_to_growth_surface``, else
        away along the collider's normal. So with both on, a moving collider
        drags the fur along and a still one pats it down.
    shrink : bool, default False
        Shrink colliding curves while they rotate (Stiff and Bend only).
    scale_minimum : float or (C,) array, default 0.5, per curve
        Scale Minimum, in (0, 1]: the smallest scale a segment shrinks to.
    scale_angle : float, default 90
        Scale Angle, degrees > 0: a segment's rotation angle at which it
        reaches ``scale_minimum``; the scale ramps linearly from 1 at 0
        degrees and is clamped beyond.
    recovery_rate : float or (C,) array, default 0.2, per curve
        Recovery Rate, 0..1: fraction of the remaining deviation from the
        recovery target recovered per frame (1 = back at once). Recovery
        stops where the curve would collide again.
    plasticity : float or (C,) array, default 0, per curve
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
    collision_offset : float or (C,) array, default 0, per curve
        Distance (world units, 0..1e6) kept between curves and colliders. A
        collider's own ``offset`` overrides it for that collider (one value
        for every curve: the collider's own offset is not mapped).
    clearance_margin : float or (C,) array, default 0, per curve
        Extra distance (world units, 0..1e6) added to whichever offset
        applies to a curve and a collider (the setting's or the collider's
        own), e.g. a bound on how far a drawn spline strays from its control
        polygon.

        How per-curve distances are kept: each collider is tested as offset
        *shells* (one BVH each), the curves grouped by the distance
        ``offset + clearance_margin`` they need from it. One distance for
        every curve is one shell, as with plain numbers. Up to
        ``tolerances.OFFSET_LEVELS`` distinct distances each get their own
        shell, exactly. More are rounded UP to at most that many levels: the
        range from the smallest to the largest distance is cut into
        ``OFFSET_LEVELS`` equal bins, and every curve of a bin is kept at
        the largest distance asked for in its bin. A curve is never kept
        closer than it asked, and at most one bin width, ``(largest -
        smallest) / OFFSET_LEVELS``, farther. (So past ``OFFSET_LEVELS``
        distinct distances, where a curve is kept depends on the range of
        the others' too, never on their order; :meth:`take` keeps the whole
        set's levels for a subset.)
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
    follow_collider_motion: bool = False
    clearance_margin: float = 0.0

    def __post_init__(self):
        def num(name, lo=None, hi=None, lo_open=False):
            v = getattr(self, name)
            if name in PER_CURVE and isinstance(v, (np.ndarray, list, tuple)):
                per_curve(name, v, lo, hi, lo_open)
                return
            if isinstance(v, (bool, np_bool)) or not isinstance(v, numbers.Real):
                what = " or a (C,) array of numbers" if name in PER_CURVE else ""
                raise SettingsError(f"Settings.{name} must be a number{what}, got {v!r}")
            if not math.isfinite(v):
                raise SettingsError(f"Settings.{name} must be finite, got {v!r}")
            if lo is not None and (v < lo or (lo_open and v == lo)):
                op = ">" if lo_open else ">="
                raise SettingsError(f"Settings.{name} must be {op} {lo}, got {v!r}")
            if hi is not None and v > hi:
                raise SettingsError(f"Settings.{name} must be <= {hi}, got {v!r}")

        def per_curve(name, v, lo, hi, lo_open):
            """Validate a parameter map and store it as a read-only float64 copy."""
            try:
                a = np.asarray(v)
            except Exception as exc:  # ragged lists
                raise SettingsError(
                    f"Settings.{name} must be a number or a (C,) array of numbers: {exc}"
                ) from None
            if a.ndim != 1:
                raise SettingsError(
                    f"Settings.{name} must be a number or a (C,) array (one value per "
                    f"curve), got an array of shape {a.shape}")
            if a.dtype.kind not in "iuf":
                raise SettingsError(
                    f"Settings.{name} must hold numbers (float or int), got dtype {a.dtype}")
            a = np.array(a, dtype=np.float64)  # (a copy: the caller's array may change)
            bad = ~np.isfinite(a)
            if bad.any():
                i = int(np.argmax(bad))
                raise SettingsError(
                    f"Settings.{name} must be finite: curve {i} has {float(a[i])!r}")
            if lo is not None:
                bad = a <= lo if lo_open else a < lo
                if bad.any():
                    i = int(np.argmax(bad))
                    op = ">" if lo_open else ">="
                    raise SettingsError(
                        f"Settings.{name} must be {op} {lo}: curve {i} has {float(a[i])!r}")
            if hi is not None and (a > hi).any():
                i = int(np.argmax(a > hi))
                raise SettingsError(
                    f"Settings.{name} must be <= {hi}: curve {i} has {float(a[i])!r}")
            a += 0.0  # -0.0 -> 0.0: equal values, equal bytes (hash)
            a.flags.writeable = False
            object.__setattr__(self, name, a)

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
        ma = self.max_angle
        if isinstance(ma, np.ndarray):
            below = ma < self.rotation_precision
            if below.any():
                i = int(np.argmax(below))
                raise SettingsError(
                    f"Settings.max_angle must be >= rotation_precision "
                    f"({self.rotation_precision!r}): curve {i} has {float(ma[i])!r}")
        elif ma < self.rotation_precision:
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
        num("collision_offset", 0.0, MAX_DISTANCE)
        num("clearance_margin", 0.0, MAX_DISTANCE)
        for name in ("attract_to_growth_surface", "shrink", "recover_pinched",
                     "follow_collider_motion"):
            flag(name)
        if self.threads is not None:
            if isinstance(self.threads, (bool, np_bool)) or not isinstance(
                self.threads, numbers.Integral
            ):
                raise SettingsError("Settings.threads must be a positive integer or None")
            num("threads", 1, 1024)

    # ----------------------------------------------------------- comparison
    def __eq__(self, other):
        if other.__class__ is not self.__class__:
            return NotImplemented
        for f in fields(self):
            a, b = getattr(self, f.name), getattr(other, f.name)
            arr_a, arr_b = isinstance(a, np.ndarray), isinstance(b, np.ndarray)
            if arr_a or arr_b:
                if not (arr_a and arr_b and a.shape == b.shape and np.array_equal(a, b)):
                    return False
            elif a != b:
                return False
        return True

    def __hash__(self):
        return hash(tuple(
            ("map", v.shape, v.tobytes()) if isinstance(v, np.ndarray) else v
            for v in (getattr(self, f.name) for f in fields(self))))

    # ------------------------------------------------------- parameter maps
    @property
    def mapped(self) -> tuple:
        """Names of the fields given as per-curve arrays (``()``: none)."""
        return tuple(n for n in PER_CURVE if isinstance(getattr(self, n), np.ndarray))

    def check_curve_count(self, n_curves: int) -> None:
        """Raise :class:`SettingsError` unless every per-curve array has
        ``n_curves`` values (the message names the field, its length and the
        curve count)."""
        for name in self.mapped:
            n = len(getattr(self, name))
            if n != n_curves:
                raise SettingsError(
                    f"Settings.{name} has {n} values but there are {n_curves} curves "
                    f"(a parameter map needs one value per curve)")

    def per_curve(self, name: str, curves=None):
        """The value of field ``name`` for ``curves`` (an index array): the
        number itself when it is not mapped, else its array's values at
        ``curves`` (the whole array for None)."""
        v = getattr(self, name)
        if isinstance(v, np.ndarray):
            return v if curves is None else v[curves]
        return v

    def take(self, curves) -> Settings:
        """These settings for the curves ``curves`` (an index or bool array)
        only: every per-curve array indexed by it (a solver of those curves).

        A solver of the subset keeps each curve exactly where a solver of all
        curves would: where the whole set's clearances are rounded to levels
        (more than ``tolerances.OFFSET_LEVELS`` distinct distances, see
        ``Collision Offset``), the subset remembers those levels
        (:meth:`clearance_rounding`), not only its own values. (That memory is
        not part of the value: it does not take part in ``==``.)
        """
        if not self.mapped:
            return self
        out = replace(self, **{n: getattr(self, n)[curves] for n in self.mapped})
        if "collision_offset" in self.mapped or "clearance_margin" in self.mapped:
            object.__setattr__(out, "_whole", getattr(self, "_whole", None) or self)
        return out

    def clearance_rounding(self, collider):
        """The levels the clearances of ``collider`` are rounded up to when
        these settings were taken (:meth:`take`) from a larger set whose
        distances need rounding (levels of that set), else None (a solver
        rounds the curves' own distances, if need be)."""
        whole = getattr(self, "_whole", None)
        if whole is None:
            return None
        cache = whole.__dict__.setdefault("_levels", {})
        key = collider.offset
        if key not in cache:
            dist = collider.clearance_distances(whole.collision_offset, whole.clearance_margin)
            levels = None
            if isinstance(dist, np.ndarray) and len(np.unique(dist)) > tol.OFFSET_LEVELS:
                from .collider import clearance_levels  # (collider.py: the rule)

                levels = clearance_levels(dist)[0]
            if len(cache) >= 16:
                cache.clear()
            cache[key] = levels
        return cache[key]

    def replace(self, **changes) -> Settings:
        """Return a copy with ``changes`` applied (validated)."""
        unknown = set(changes) - {f.name for f in fields(self)}
        if unknown:
            raise SettingsError(f"Settings has no field {sorted(unknown)[0]!r}")
        return replace(self, **changes)

    def to_dict(self) -> dict:
        """Plain ``dict`` of every field (presets, Blender properties); a
        per-curve field is a (writable) copy of its array."""
        return asdict(self)
