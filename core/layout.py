"""Blender's curve layout: ``points`` (P, 3) + ``offsets`` (C+1,), shared checks."""

from __future__ import annotations

import numpy as np

from .errors import InputError


def check_offsets(offsets, min_curves=1) -> np.ndarray:
    """Validate curve offsets: curve ``i`` is ``points[offsets[i]:offsets[i + 1]]``.

    Parameters
    ----------
    offsets : (C+1,) array_like of int
        Starts at 0, every curve has at least 2 points.
    min_curves : int
        Fewest curves accepted.

    Returns
    -------
    (C+1,) int64 ndarray

    Raises
    ------
    InputError
        The message names the curve at fault.
    """
    try:
        off = np.asarray(offsets)
    except Exception as exc:
        raise InputError(f"offsets must be a 1-D integer array: {exc}") from None
    if off.ndim != 1 or len(off) < min_curves + 1:
        raise InputError(
            f"offsets must be a 1-D array of C+1 >= {min_curves + 1} integers, "
            f"got shape {off.shape}"
        )
    if not np.issubdtype(off.dtype, np.integer):
        raise InputError(f"offsets must be integers, got dtype {off.dtype}")
    off = off.astype(np.int64)
    if off[0] != 0:
        raise InputError(f"offsets must start at 0, got {int(off[0])}")
    sizes = np.diff(off)
    if (sizes < 2).any():
        i = int(np.argmax(sizes < 2))
        if sizes[i] <= 0:
            raise InputError(f"offsets must increase: curve {i} has {int(sizes[i])} points")
        raise InputError(f"curve {i} has only 1 point; every curve needs at least 2")
    return off
