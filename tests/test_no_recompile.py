"""Nothing retraces or recompiles when only values change: damper positions and coefficients,
tolerances, initial states, masses/springs, snapshots, the reduction basis.

Counted with ``jax.monitoring``: a trace of a jitted function records a jaxpr-trace event, every
executable built (compiled or loaded from the persistent cache) a backend-compile event. The first
call of each case uses a static configuration (its own ``dofs``, or shape) that no other test uses,
so its solver's jitted function is traced exactly once there; every later call with new values must
record no event at all. ``benchmarks/compile.py`` does the same for every entry point at n = 300.
"""

import contextlib

import diffrax
import jax
import numpy as np

import mikota_jax as mj
from mikota_jax._rom.pod import pod

TRACE = "/jax/core/compile/jaxpr_trace_duration"
BACKEND = "/jax/core/compile/backend_compile_duration"
N = 20
TS = np.linspace(0.0, 4.0, 41)
MASSES, SPRINGS = 1.0 / np.arange(1, N + 1), N + 1.0 - np.arange(1, N + 1)


def chain(position=7.0, coefficient=1.0, m=1.0, k=1.0):
    return mj.mikota_chain(N, m, k, dampers=[mj.GroundedDamper(position, coefficient)])


def unit(dof, value=1.0):
    x = np.zeros(N)
    x[dof - 1] = value
    return x


X0 = unit(3)


@contextlib.contextmanager
def recorded():
    """The (event, function) of every trace and backend compile inside the block."""
    log = []

    def listener(event, seconds, **kwargs):
        if event in (TRACE, BACKEND):
            log.append((event.rsplit("/", 1)[-1], kwargs.get("fun_name")))

    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        yield log
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)


def assert_traced_once(first, main: str, changes: dict):
    """``first()`` traces ``main`` once; each call in ``changes`` traces and compiles nothing."""
    with recorded() as log:
        jax.block_until_ready(first())
    traces = [f for e, f in log if e == TRACE.rsplit("/", 1)[-1] and f == main]
    assert len(traces) == 1, f"first call traced {main} {len(traces)} times: {log}"
    for what, call in changes.items():
        with recorded() as log:
            jax.block_until_ready(call())
        assert not log, f"new {what} only: traced/compiled again: {log}"


def solver_changes(call, tolerances=True) -> dict:
    changes = {
        "damper position": lambda: call(chain(7.5)),
        "damper position (integer)": lambda: call(chain(12, 1.0)),
        "damper coefficient": lambda: call(chain(7.0, 2.5)),
        "x0/v0": lambda: call(chain(), x0=unit(5, 0.5), v0=unit(1, 0.2)),
        "masses/springs": lambda: call(mj.chain(MASSES * 1.1, SPRINGS * 0.9,
                                                [mj.GroundedDamper(7.0, 1.0)])),
        "m, k": lambda: call(chain(m=1.3, k=0.8)),
    }
    if tolerances:
        changes["rtol/atol"] = lambda: call(chain(), rtol=1e-6, atol=1e-9)
    return changes


def test_simulate_full_model_traces_once():
    def call(system, x0=X0, v0=None, rtol=1e-8, atol=1e-10):
        return mj.solve(system, TS, x0, v0, dofs=[2, 5, 11], method=mj.ODE(rtol=rtol, atol=atol))

    assert_traced_once(lambda: call(chain()), "simulate_with_result", solver_changes(call))


def test_exact_solve_full_model_traces_once():
    def call(system, x0=X0, v0=None):
        return mj.solve(system, TS, x0, v0, dofs=[3, 17], velocity=True, method=mj.Spectral())

    # a chain with a damper takes the spectral path
    assert_traced_once(lambda: call(chain()), "spectral_solve_with_result",
                       solver_changes(call, tolerances=False))


def test_exact_solve_dense_path_traces_once():
    def call(system, x0=X0, v0=None):
        return mj.solve(system, TS, x0, v0, dofs=[4, 18], velocity=True,
                        method=mj.DenseExponential())

    assert_traced_once(lambda: call(chain()), "_exact", solver_changes(call, tolerances=False))


def test_reduced_model_and_pod_trace_once():
    q = np.random.default_rng(0).standard_normal((N, 23))  # a shape no other test uses
    assert_traced_once(lambda: pod(q), "_pod_svd",
                       {"snapshots": lambda: pod(2.0 * q[:, ::-1])})
    basis = pod(q).basis(6)
    other = pod(q[:, ::-1] + 0.1 * q).basis(6)

    def call(system, b=basis, x0=X0, v0=None, rtol=1e-8, atol=1e-10):
        return mj.solve(mj.reduce(system, mj.Projection(b)), TS, x0, v0, dofs=[4, 9],
                        method=mj.ODE(diffrax.Tsit5(), rtol=rtol, atol=atol))

    changes = solver_changes(call)
    changes["basis"] = lambda: call(chain(), b=other)
    assert_traced_once(lambda: call(chain()), "simulate_with_result", changes)


def test_error_norms_of_reduced_models_of_one_shape_share_one_program():
    # a reduced model's stats are static (here its shifts): they must not enter the compiled
    # norms, or every new model of the same rank would compile them again
    io = mj.IOModel(chain(), unit(3), cx=unit(10))

    def error(shifts):
        reduced = mj.reduce(io, mj.RationalKrylov(np.array(shifts), unit(3)))
        assert reduced.model.rank == 4
        return (io - reduced).h2_norm(), reduced.frequency_response(np.linspace(0.0, 3.0, 5))

    jax.block_until_ready(error([1.1j, 5.1j]))
    with recorded() as log:
        jax.block_until_ready(error([2.3j, 7.3j]))
    assert not log, f"a new reduced model of the same shape traced/compiled again: {log}"
