"""The parameter map: named parameters on an assembled system equal the system built from them,
bit for bit, and the values are checked once at the entry, never inside the map."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mikota_jax as mj
from mikota_jax._model.parameters import check_parameters, with_parameters


def leaves_equal(a, b):
    left, right = jax.tree.leaves(a), jax.tree.leaves(b)
    assert jax.tree.structure(a) == jax.tree.structure(b)
    for x, y in zip(left, right):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def test_mapped_parameters_equal_the_rebuilt_system_bit_for_bit():
    dampers = [mj.GroundedDamper(3.0, 0.5), mj.RelativeDamper((2, 5), 0.2)]
    base = mj.mikota_chain(8, dampers=dampers, internal_damping=(mj.Rayleigh(0.1, 0.01),
                                                                 mj.ModalDamping(0.02)))
    mapped = with_parameters(base, dict(
        m=jnp.asarray(2.0), k=jnp.asarray(3.0), positions=jnp.array([4.5]),
        coefficients=jnp.array([0.7]), relative_coefficients=jnp.array([0.3]),
        alpha=jnp.asarray(0.2), beta=jnp.asarray(0.02), zeta=jnp.asarray(0.05)))
    rebuilt = mj.mikota_chain(8, 2.0, 3.0, [mj.GroundedDamper(4.5, 0.7),
                                            mj.RelativeDamper((2, 5), 0.3)],
                              internal_damping=(mj.Rayleigh(0.2, 0.02), mj.ModalDamping(0.05)))
    leaves_equal(mapped, rebuilt)
    masses, springs = jnp.linspace(1.0, 2.0, 8), jnp.linspace(3.0, 1.0, 8)
    leaves_equal(with_parameters(base, dict(masses=masses, springs=springs)),
                 mj.chain(masses, springs, dampers, internal_damping=(mj.Rayleigh(0.1, 0.01),
                                                                      mj.ModalDamping(0.02))))


def test_values_are_checked_at_the_entry_eagerly_and_under_jit():
    system = mj.mikota_chain(6, dampers=[mj.GroundedDamper(3.0, 0.5)])
    with pytest.raises(ValueError, match=r"position must lie in \[1, 6\]"):
        check_parameters(system, dict(positions=jnp.array([7.0])))
    with pytest.raises(ValueError, match="coefficient must be finite and >= 0"):
        check_parameters(system, dict(coefficients=jnp.array([-1.0])))
    checked = jax.jit(lambda p: check_parameters(system, dict(positions=p))["positions"])
    with pytest.raises(Exception, match=r"position must lie in \[1, 6\]"):
        checked(jnp.array([0.5]))
    with pytest.raises(ValueError, match="shape"):
        check_parameters(system, dict(positions=jnp.array([2.0, 3.0])))
    with pytest.raises(ValueError, match="need Rayleigh damping"):
        with_parameters(system, dict(alpha=jnp.asarray(0.1)))
    with pytest.raises(ValueError, match="unknown"):
        with_parameters(system, dict(mass=jnp.asarray(0.1)))
