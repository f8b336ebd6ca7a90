"""The shared test helpers are right where the tests rely on them."""

import jax.numpy as jnp
import numpy as np

from .helpers import central_differences, rotation_field, tree_allclose


def test_central_differences_of_a_known_jacobian():
    fn = lambda x: np.array([x[0] ** 2 * x[1], np.sin(x[1])])
    x = np.array([1.5, 0.3])
    exact = np.array([[2 * x[0] * x[1], x[0] ** 2], [0.0, np.cos(x[1])]])
    h = 1e-5
    # Error O(h²·|f'''|) ≈ 1e-10 here, plus round-off ε|f|/h ≈ 1e-11.
    np.testing.assert_allclose(central_differences(fn, x, h), exact, rtol=0, atol=1e-9)
    np.testing.assert_allclose(central_differences(np.exp, 0.7, h), np.exp(0.7), rtol=1e-9)


def test_tree_allclose_compares_structure_and_treats_nan_as_equal():
    a = {"t": np.array([1.0, np.nan]), "n": np.array(3)}
    assert tree_allclose(a, {"t": np.array([1.0, np.nan]), "n": np.array(3)})
    assert not tree_allclose(a, {"t": np.array([1.0 + 1e-9, np.nan]), "n": np.array(3)})
    assert tree_allclose(a, {"t": np.array([1.0 + 1e-9, np.nan]), "n": np.array(3)}, atol=1e-8)
    assert not tree_allclose(a, {"t": np.array([1.0, np.nan])})


def test_rotation_field_is_the_harmonic_oscillator():
    np.testing.assert_array_equal(rotation_field(0.0, jnp.array([2.0, 3.0]), None), [3.0, -2.0])
