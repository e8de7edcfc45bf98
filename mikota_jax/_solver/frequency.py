"""Frequency response (transfer functions) of full and reduced models, differentiable.

H(i omega) = (K - omega^2 M + i omega D)^-1 B: the steady-state complex amplitude of the
displacements under forces B e^(i omega t). For a ``ReducedModel`` on Phi, H_r = Phi (K_r -
omega^2 M_r + i omega D_r)^-1 Phi^T B: the natural check of moment matching (``Krylov``
matches H and its derivatives at omega = 0) and of any reduction in the frequency domain
(Antoulas, "Approximation of Large-Scale Dynamical Systems", SIAM 2005, ch. 4).
"""

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._custom_types import Array, Float
from .._errors import MARK, array_module, as_float, check, check_dense_memory, raises_value_error
from .._model.reduced import ReducedModel
from .._model.system import SecondOrderSystem
from .ode import check_dofs


@eqx.filter_jit
def _response(system, basis, omegas, forces, rows):
    m, d, k = system.dense()
    d = jnp.zeros_like(k) if d is None else d
    if basis is not None:
        forces = basis.T @ forces
    lift = (basis[rows] if basis is not None else jnp.eye(k.shape[0])[rows]).astype(jnp.complex128)

    def one(omega):
        matrix = jax.lax.complex(k - omega**2 * m, omega * d)
        return lift @ jnp.linalg.solve(matrix, forces.astype(jnp.complex128))

    return jax.lax.map(one, omegas)


@raises_value_error
def frequency_response(model, omegas, inputs, *, dofs: Sequence[int] | None = None
                       ) -> Float[Array, "F d s"]:
    """H(i omega) of ``model`` (a ``SecondOrderSystem`` or ``ReducedModel``) at the angular
    frequencies ``omegas`` (F,) (rad per unit time, >= 0) for the force directions ``inputs``
    ((n,) or (n, s), full coordinates): complex128 (F, d, s), rows the 1-based ``dofs`` (default
    all). One dense solve per frequency in the model's size (O(n^3) for a full model: meant for
    reduced models and moderate n); ``jax.grad`` passes through (of a real function of it)."""
    if isinstance(model, ReducedModel):
        system, basis = model.system, model.basis
    elif isinstance(model, SecondOrderSystem):
        system, basis = model, None
    else:
        raise ValueError(MARK + "model must be a SecondOrderSystem or a ReducedModel, got "
                         f"{type(model).__name__}.")
    n = model.size
    omegas = as_float(omegas, "omegas")
    if omegas.ndim != 1 or omegas.shape[0] < 1:
        raise ValueError(MARK + f"omegas must be a non-empty (F,) array, got {omegas.shape}.")
    xp = array_module(omegas)
    values = np.asarray(omegas) if xp is np else omegas
    omegas = check(omegas, ~xp.all(xp.isfinite(values) & (values >= 0)),
                   "omegas must be finite and >= 0.")
    forces = as_float(inputs, "inputs")
    forces = forces[:, None] if forces.ndim == 1 else forces
    if forces.ndim != 2 or forces.shape[0] != n:
        raise ValueError(MARK + f"inputs must be (n,) or (n, s) with n = {n}, got "
                         f"{forces.shape}.")
    rows = np.asarray(check_dofs(dofs, n)) - 1
    check_dense_memory(system.size, 6, "frequency_response")
    return _response(system, basis, omegas, forces, rows)
