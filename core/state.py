"""The solver's per-curve state: what one step hands the next.

A :class:`SolverState` is plain numpy arrays, one row per curve (or per
segment, for Soft's rotations), kept in each curve's *local frame* (see
``rotations.curve_frames``), so that it follows the animated growth surface.
The step (:class:`core.step.StepContext`) reads it at its start and writes the
next one at its end; :attr:`core.Solver.state` snapshots and restores it.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

#: Version of the snapshot layout (``Solver.state['meta'][0]``).
STATE_VERSION = 1


def identity_rows(n: int) -> np.ndarray:
    """(n, 4) float64 identity quaternions (1, 0, 0, 0), read-only: one row
    broadcast, no memory per row (copy it to write)."""
    return np.broadcast_to(np.array([1.0, 0.0, 0.0, 0.0]), (n, 4))


def _copy(a: np.ndarray) -> np.ndarray:
    return a if not a.flags.writeable else a.copy()


@dataclass
class SolverState:
    """Per-curve state of a :class:`core.Solver` (C curves, S segments).

    Attributes
    ----------
    angle, angle_max : (C,) float64
        Stiff/Bend: the curve's rotation (radians) and the largest of this
        contact (Plasticity's reference).
    axis : (C, 3) float64
        The rotation axis, in the curve's local frame (kept from the first
        hit until the curve has recovered).
    frame : (C, 3, 3) float64
        The transported reference of each active curve's local frame.
    active : (C,) bool
        Has a non-identity local state.
    hold : (C,) bool
        No recovery (out of a pinch with ``recover_pinched`` off).
    pinched : (C,) bool
        Root inside a collider at the last step.
    stiff : (C,) bool
        A Bend curve solved as Stiff (bending could not clear it).
    contact : (C,) bool
        COLLIDING at the last step (where the next search starts, rigid.Plan).
    delta : (C,) float64
        The last step's change: Stiff/Bend the angle's, Soft the fraction of
        the recovery step a blocked curve took.
    quat, quat_max : (S, 4) float64
        Soft: each segment's rotation (w, x, y, z), local frame, and the
        largest of this contact. Until a Soft step stores its own, both are one
        read-only identity row broadcast to (S, 4) (:func:`identity_rows`): Stiff
        and Bend never use them, and at 200,000 curves x 8 CVs two real arrays
        would take 90 MB.
    """

    angle: np.ndarray
    angle_max: np.ndarray
    axis: np.ndarray
    frame: np.ndarray
    active: np.ndarray
    hold: np.ndarray
    pinched: np.ndarray
    stiff: np.ndarray
    contact: np.ndarray
    delta: np.ndarray
    quat: np.ndarray
    quat_max: np.ndarray

    #: Snapshot keys and their shapes (C curves, S segments).
    SHAPES = {
        "angle": ("C",), "angle_max": ("C",), "axis": ("C", 3), "frame": ("C", 3, 3),
        "active": ("C",), "hold": ("C",), "pinched": ("C",), "stiff": ("C",),
        "contact": ("C",), "delta": ("C",), "quat": ("S", 4), "quat_max": ("S", 4),
    }
    #: Only Soft mode carries per-segment rotations.
    SOFT = ("quat", "quat_max")
    #: Keys a snapshot may lack (made before they existed): fresh values. They
    #: only steer where the next search starts.
    OPTIONAL = ("contact", "delta")
    _BOOL = ("active", "hold", "pinched", "stiff", "contact")

    @classmethod
    def fresh(cls, n_curves: int, n_segments: int) -> SolverState:
        """The state of curves with no history."""
        C, S = n_curves, n_segments
        ident = identity_rows(S)
        return cls(
            angle=np.zeros(C), angle_max=np.zeros(C), axis=np.zeros((C, 3)),
            frame=np.zeros((C, 3, 3)), active=np.zeros(C, bool), hold=np.zeros(C, bool),
            pinched=np.zeros(C, bool), stiff=np.zeros(C, bool), contact=np.zeros(C, bool),
            delta=np.zeros(C), quat=ident, quat_max=ident,
        )

    def copy(self) -> SolverState:
        """A copy (the read-only identity rows of a fresh state are shared, not copied)."""
        return SolverState(**{f.name: _copy(getattr(self, f.name)) for f in fields(self)})

    def rows(self, curves, seg) -> dict:
        """Copies of the rows of ``curves`` (C,) bool and their segments ``seg``
        (S,) bool (see :meth:`put_rows`)."""
        out = {}
        for f in fields(self):
            a = getattr(self, f.name)
            out[f.name] = a[seg if f.name in self.SOFT else curves].copy()
        return out

    def put_rows(self, curves, seg, rows: dict) -> None:
        """Write back :meth:`rows` (an invalid curve keeps its state)."""
        for f in fields(self):
            a, sel = getattr(self, f.name), seg if f.name in self.SOFT else curves
            if not a.flags.writeable:  # identity rows (no Soft step yet)
                if np.array_equal(a[sel], rows[f.name]):
                    continue
                a = a.copy()
                setattr(self, f.name, a)
            a[sel] = rows[f.name]

    @classmethod
    def from_arrays(cls, arrays: dict, n_curves: int, n_segments: int) -> SolverState:
        """A state from checked snapshot arrays; missing ones are fresh."""
        st = cls.fresh(n_curves, n_segments)
        for k, a in arrays.items():
            dtype = bool if k in cls._BOOL else np.float64
            setattr(st, k, np.asarray(a).astype(dtype).copy())
        return st
