"""core.pipeline.surface_values: vertex values read at the closest surface point."""

import numpy as np
import pytest

from core.errors import InputError
from core.pipeline import surface_values


def grid(n=6):
    x, y = np.meshgrid(np.linspace(-1, 1, n), np.linspace(-1, 1, n), indexing="ij")
    V = np.stack([x.ravel(), y.ravel(), 0.1 * np.sin(3 * x.ravel())], 1)
    i, j = np.meshgrid(np.arange(n - 1), np.arange(n - 1), indexing="ij")
    a = (i * n + j).ravel()
    F = np.concatenate([np.stack([a, a + n, a + n + 1], 1), np.stack([a, a + n + 1, a + 1], 1)])
    return V, F


def test_linear_values_are_reproduced_on_the_surface():
    V, F = grid()
    rng = np.random.default_rng(0)
    face = rng.integers(0, len(F), 200)
    bary = rng.dirichlet(np.ones(3), 200)
    P = np.einsum("ij,ijk->ik", bary, V[F[face]])  # points exactly on the surface
    coef = np.array([0.3, -1.2, 2.0])
    values = V @ coef + 0.5
    np.testing.assert_allclose(surface_values(V, F, values, P), P @ coef + 0.5, atol=1e-9)


def test_points_off_the_surface_read_their_closest_point():
    V, F = grid()
    values = np.zeros(len(V))
    values[np.argmax(V[:, 0] + V[:, 1])] = 1.0  # corner (1, 1) only
    near_corners = np.array([[1.2, 1.1, 0.05], [-1.0, -1.0, 0.05]])  # beyond the rim
    np.testing.assert_allclose(surface_values(V, F, values, near_corners), [1.0, 0.0],
                               atol=1e-9)


def test_wrong_value_count_is_an_error():
    V, F = grid()
    with pytest.raises(InputError, match="one entry per vertex"):
        surface_values(V, F, np.zeros(len(V) - 1), V[:2])
