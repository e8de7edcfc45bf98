"""``reduce(problem, strategy)``: every strategy gives exactly the basis its builder gives, ``rank``
is the final column count, an unreachable rank is a one-line error, and the reduced model is a
pytree that ``jit``, ``vmap`` and ``grad`` pass through."""

import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mikota_jax as mj
from mikota_jax._estimation.enrichment import enriched_reduce
from mikota_jax._model.reduced import galerkin
from mikota_jax._rom.classic import (
    craig_bampton_basis,
    extend_basis,
    krylov_basis,
    modal_basis,
    modal_static_basis,
)
from mikota_jax._rom.interpolatory import band_shifts, irka_basis, rational_krylov_basis
from mikota_jax._rom.pod import pod

N = 30
EXACT = 1e-14  # the same numbers: the strategy calls the builder, nothing in between


def damped(position=7.0, coefficient=2.0, n=N):
    return mj.mikota_chain(n, dampers=[mj.GroundedDamper(position, coefficient)])


def scene(n=12, rank=None, energy=None):
    reduction = {"snapshots": [0.0, 5.0]}
    reduction.update({"rank": rank} if rank is not None else {"energy": energy})
    return mj.app.load_scene({
        "name": "small", "chain": {"type": "mikota", "n": n, "m": 1.0, "k": 1.0},
        "damper": [{"type": "grounded", "position": 4.0, "coefficient": 0.5}],
        "initial": {"displacement": {"3": 1.0}}, "time": {"end": 10.0, "step": 0.05},
        "reduction": reduction})


def same(a, b):
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape
    assert np.max(np.abs(a - b)) <= EXACT


@pytest.mark.slow  # the builders have their own tests (test_classic, test_interpolatory)
def test_structural_strategies_give_exactly_the_builders_basis():
    system = damped()
    force = np.asarray(mj.unit_vector(N, 3))
    same(mj.reduce(system, mj.Modal(8)).basis, modal_basis(system, 8))
    same(mj.reduce(system, mj.Krylov(6, force)).basis, krylov_basis(system, 6, force))
    shifts = np.array([0.1 + 1j, 0.1 + 3j])
    same(mj.reduce(system, mj.RationalKrylov(shifts, force)).basis,
         rational_krylov_basis(system, shifts, force))
    model = mj.reduce(system, mj.RationalKrylov(3, force))
    same(model.basis, rational_krylov_basis(system, band_shifts(system, 3, force), force))
    assert model.stats.shifts == tuple(complex(z) for z in band_shifts(system, 3, force))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # a short IRKA need not settle; both runs are the same
        found = irka_basis(system, 8, force, 20.0, iterations=3)
        model = mj.reduce(system, mj.IRKA(8, force, 20.0, iterations=3))
    same(model.basis, found.basis)
    assert (model.stats.iterations, model.stats.converged) == (found.iterations, found.converged)
    # the strategies' own modes count reproduces the builder at that count
    model = mj.reduce(system, mj.ModalStatic(10, moments=2))
    same(model.basis, modal_static_basis(system, model.stats.modes, moments=2)[:, :10])
    model = mj.reduce(system, mj.CraigBampton(12, states=mj.unit_vector(N, 3)))
    same(model.basis, craig_bampton_basis(system, model.stats.modes,
                                          states=mj.unit_vector(N, 3))[:, :12])


def test_projection_is_the_galerkin_model_of_the_basis():
    system = damped()
    basis = modal_basis(system, 5)
    model, old = mj.reduce(system, mj.Projection(basis)), galerkin(system, basis)
    for a, b in zip(model.system.dense(), old.system.dense(), strict=True):
        same(a, b)
    assert model.stats.strategy == "Projection" and model.rank == 5


def test_pod_of_a_scene_is_the_pod_of_its_snapshots():
    s = scene(rank=4)
    states = mj.solve(s.system, s.ts, s.x0, method=mj.Spectral()).displacement
    window = np.asarray(s.ts) <= 5.0 + 1e-9
    reference = pod(jnp.asarray(np.asarray(states)[window].T))
    model = mj.reduce(s, s.reduction)
    same(model.basis, reference.basis(4))
    same(model.stats.singular_values, reference.singular_values)
    assert (model.stats.strategy, model.rank, model.stats.snapshots) == ("POD", 4, 101)
    # the scene's own run: the same basis
    same(mj.run_scene(s).model.basis, model.basis)
    # an energy rule and a window of None (the whole grid)
    model = mj.reduce(s, mj.POD(energy=0.999))
    assert model.stats.snapshots == 201
    assert model.rank == model.stats.decomposition.rank_for_energy(0.999)


@pytest.mark.slow  # EnrichedPOD.basis calls the builder; test_enrichment tests the builder
def test_enriched_pod_is_the_enriched_basis():
    s = scene(rank=5)
    basis, stats = enriched_reduce(s, ("coefficients",))
    model = mj.reduce(s, mj.EnrichedPOD(("coefficients",)))
    same(model.basis, basis)
    assert (model.rank, model.stats.snapshots) == (stats.rank, stats.snapshots) == (5, 202)


@pytest.mark.parametrize("rank", [6, 11, 20])
def test_craig_bampton_and_modal_static_deliver_the_requested_columns(rank):
    system = mj.mikota_chain(N, dampers=[mj.GroundedDamper(7.0, 2.0),
                                         mj.GroundedDamper(18.5, 1.0)])
    x0 = mj.unit_vector(N, 3)
    for strategy in (mj.CraigBampton(rank), mj.CraigBampton(rank, states=x0),
                     mj.ModalStatic(rank), mj.ModalStatic(rank, moments=2, loads=x0)):
        model = mj.reduce(system, strategy)
        assert model.basis.shape == (N, rank) and model.stats.rank == rank
        assert np.max(np.abs(model.basis.T @ model.basis - np.eye(rank))) < 1e-12
        assert model.stats.modes < rank  # the rest are static directions


def one_line(excinfo):
    message = str(excinfo.value)
    assert "\n" not in message
    return message


def test_an_unreachable_rank_is_a_one_line_error():
    system = damped()
    with pytest.raises(ValueError, match=r"rank must be an integer in 1\.\.30") as e:
        mj.reduce(system, mj.Modal(N + 1))
    one_line(e)
    # an undamped chain forced along a mode: the Krylov space K^-1 M u = u / omega^2 is one
    # direction, whatever the rank asked for
    undamped = mj.mikota_chain(10)
    mode = np.asarray(mj.analytic.mode_shape(10, 2))
    force = np.asarray(undamped.dense()[0]) @ mode  # M u: K^-1 M u = u / omega^2
    with pytest.raises(ValueError, match=r"Krylov: rank = 3 .* at most 1 columns") as e:
        mj.reduce(undamped, mj.Krylov(3, force))
    one_line(e)
    # a POD rank above the snapshots' numerical rank: an undamped start in mode 2 is x(t) =
    # cos(2 t) u_2, one direction (undamped: the damped modes do not apply, the exponential does)
    s = eqx.tree_at(lambda s: (s.system, s.x0, s.method), scene(rank=3),
                    (mj.mikota_chain(12), jnp.asarray(mj.analytic.mode_shape(12, 2)),
                     mj.DenseExponential()))
    with pytest.raises(ValueError, match=r"rank = 3 exceeds the numerical rank 1") as e:
        mj.reduce(s, mj.POD(rank=3))
    one_line(e)
    for strategy in (mj.CraigBampton(N + 1), mj.ModalStatic(N + 1)):
        with pytest.raises(ValueError, match=r"rank must be an integer in 1\.\.30") as e:
            mj.reduce(system, strategy)
        one_line(e)


def test_snapshot_strategies_need_a_scene():
    with pytest.raises(ValueError, match="problem must be a Scene for POD") as e:
        mj.reduce(damped(), mj.POD(rank=3))
    one_line(e)
    with pytest.raises(ValueError, match="problem must be a Scene for EnrichedPOD"):
        mj.reduce(damped(), mj.EnrichedPOD())
    with pytest.raises(ValueError, match="strategy must be an AbstractReduction"):
        mj.reduce(damped(), "modal")
    with pytest.raises(ValueError, match="POD needs rank"):
        mj.POD()


def test_a_scene_gives_its_system_to_structural_strategies():
    s = scene(rank=3)
    same(mj.reduce(s, mj.Modal(4)).basis, mj.reduce(s.system, mj.Modal(4)).basis)


def test_union_of_modes_and_a_static_load_direction_holds_the_static_response():
    system = damped()
    force = np.asarray(mj.unit_vector(N, 20))
    k = np.asarray(system.dense()[2])
    static = np.linalg.solve(k, force)
    model = mj.reduce(system, mj.Union(mj.Modal(5), mj.Projection(static[:, None]
                                                                   / np.linalg.norm(static))))
    assert model.rank == 6 and [p.strategy for p in model.stats.parts] == ["Modal", "Projection"]
    same(model.basis[:, :5], modal_basis(system, 5))  # the first strategy's columns first
    same(model.basis, extend_basis(modal_basis(system, 5), static / np.linalg.norm(static)))
    # the static response lies in the span, so the reduced static solve gives it back
    kr = np.asarray(model.system.dense()[2])
    lifted = np.asarray(model.basis) @ np.linalg.solve(kr, np.asarray(model.basis).T @ force)
    assert np.max(np.abs(lifted - static)) < 1e-12 * np.max(np.abs(static))
    # a direction already in the span adds nothing
    assert mj.reduce(system, mj.Union(mj.Modal(5), mj.Modal(3))).rank == 5


def test_projection_refuses_a_basis_that_is_not_orthonormal():
    system = damped()
    basis = np.asarray(modal_basis(system, 4)) * 1.01
    with pytest.raises(ValueError, match="basis must have orthonormal columns") as e:
        mj.reduce(system, mj.Projection(basis))
    one_line(e)
    with pytest.raises(ValueError, match="basis must have shape"):
        mj.reduce(system, mj.Projection(np.eye(N + 1)[:, :3]))


def test_a_reduced_model_is_a_pytree_for_jit():
    s = scene(rank=4)
    x0 = s.x0
    for model in (mj.reduce(s, s.reduction), mj.reduce(s.system, mj.Modal(4))):
        f = jax.jit(lambda m: (m.lift(m.reduce_state(x0)), m.stats.singular_values))
        lifted, sigma = f(model)
        same(lifted, model.lift(model.reduce_state(x0)))
        assert (sigma is None) == (model.stats.decomposition is None)
        again = jax.jit(lambda m: m)(model)
        assert again.stats.strategy == model.stats.strategy and again.rank == model.rank


def test_grad_and_vmap_pass_through_a_structural_reduction():
    x0 = jnp.asarray(mj.unit_vector(N, 3))

    def energy(c):
        model = mj.reduce(damped(7.0, c), mj.Modal(10))
        return mj.Energy(5.0, x0, method=mj.DenseExponential())(model)

    c = 2.0
    # the dense energy carries ~1e-11 relative rounding (Van Loan step and doublings), so the
    # step is 1e-4 x scale, not sqrt(eps) x scale (as tests/test_docs.py): truncation ~1e-8
    h = 1e-4 * c
    central = (float(energy(c + h)) - float(energy(c - h))) / (2 * h)
    assert float(jax.grad(energy)(c)) == pytest.approx(central, rel=1e-6)
    values = jax.vmap(energy)(jnp.array([0.5, 2.0]))
    assert float(values[1]) == pytest.approx(float(energy(2.0)), rel=1e-12)
    assert float(jax.jit(energy)(2.0)) == pytest.approx(float(energy(2.0)), rel=1e-12)


def test_a_users_strategy_subclasses_abstract_reduction():
    class FirstUnitVectors(mj.AbstractReduction):
        rank: int

        def basis(self, problem):
            return jnp.eye(problem.size)[:, : self.rank], None

    model = mj.reduce(damped(), FirstUnitVectors(3))
    assert model.stats.strategy == "FirstUnitVectors" and model.rank == 3
    same(model.system.dense()[0], np.asarray(damped().dense()[0])[:3, :3])


@pytest.mark.slow  # two greedy runs (~1 min each): a full solve and a compile per iteration
def test_greedy_is_the_greedy_basis():
    from mikota_jax._estimation.greedy import greedy_reduce

    s = scene(rank=3)
    training = mj.grid(positions=np.array([[2.0], [9.0]]), coefficients=np.array([[0.1], [5.0]]))
    found = greedy_reduce(s, training, 1e-3, step=3, max_rank=9)
    model = mj.reduce(s, mj.Greedy(training, 1e-3, step=3, max_rank=9))
    same(model.basis, found.basis)
    assert (model.rank, model.stats.certified, model.stats.full_solves, model.stats.history) == (
        found.rank, found.certified, found.full_solves, found.history)
