"""pyMOR's side of the reduction comparison (``pymor_comparison.py``, which scores every model of
both libraries with one evaluation code: ``mj.LTIModel`` and its error system).

``pymor_reductions`` runs pyMOR's reductors on a second-order system given as dense numpy
matrices. No jax and no mikota_jax here.

Conventions: M x'' + D x' + K x = b u, y = cx x (pyMOR calls the damping ``E``); r is the number
of second-order DOFs of a reduced model, first-order reductors get order 2r, so every reduced
model has 2r states. Every reduced model comes back as a dense first-order realization (E, A, B,
C), G(s) = C (sE - A)^-1 B; for a second-order one pyMOR's ``to_lti`` form: E = blockdiag(I, M_r),
A = [[0, I], [-K_r, -D_r]], B = [0; B_r], C = [Cp_r, Cv_r]. Offline times are wall seconds of the
reductor's construction + ``reduce`` on a freshly built model (pyMOR caches Gramians per model
object, so no row reuses another row's Gramians).
"""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import time

import numpy as np
import scipy.linalg as sl
from pymor.algorithms.to_matrix import to_matrix
from pymor.core.logger import set_log_levels
from pymor.models.iosys import LTIModel, SecondOrderModel
from pymor.operators.numpy import NumpyMatrixOperator
from pymor.reductors import sobt
from pymor.reductors.bt import BTReductor
from pymor.reductors.h2 import IRKAReductor, TSIAReductor
from pymor.reductors.interpolation import SOBHIReductor
from pymor.reductors.mt import MTReductor
from pymor.reductors.sor_irka import SORIRKAReductor
from pymor.tools.random import new_rng

# pyMOR's default tolerance for its IRKA-type reductors, with iteration caps below its default
# 100: on this system these loops need not converge, and SOR-IRKA runs a whole IRKA (capped by
# irka_options) in each of its iterations: ~100 s per iteration at r = 80 with the inner cap 50,
# and it settled at no r >= 40 within 20 x 20 iterations in an earlier run. A capped run says
# converged = False.
TOL = 1e-4
IRKA = {"tol": TOL, "maxit": 50}
SOR_IRKA = {"tol": TOL, "maxit": 10, "irka_options": {"tol": TOL, "maxit": 10}}


def _band_shifts(so: SecondOrderModel, r: int) -> np.ndarray:
    """r shifts 0.01 + i omega_l (and conjugates) at r / 2 undamped natural frequencies spread
    evenly in index over all modes: a broadband start for bitangential Hermite interpolation."""
    omegas = np.sqrt(np.abs(sl.eigh(to_matrix(so.K, format="dense"),
                                    to_matrix(so.M, format="dense"), eigvals_only=True)))
    picked = omegas[np.round(np.linspace(0, omegas.size - 1, r // 2)).astype(int)]
    shifts = np.concatenate([0.01 + 1j * picked, 0.01 - 1j * picked])
    return shifts if r % 2 == 0 else np.append(shifts, 0.01 * omegas[0])


def _bt_then(cls):
    """Balanced truncation to 2r states, then the IRKA-type ``cls`` started from its model."""
    def reduce(so, r):
        lti = so.to_lti()
        start = BTReductor(lti).reduce(2 * r)
        reductor = cls(lti)
        return reductor.reduce(start, **IRKA), reductor
    return reduce


def _so_bhi(so, r):
    reductor = SOBHIReductor(so)
    return reductor.reduce(_band_shifts(so, r), np.ones((r, 1)), np.ones((r, 1))), reductor


def _on(cls, order, lti=False, **options):
    """(so, r) -> (reduced model, reductor): ``cls`` on the second-order model (or its LTI form)
    reduced to ``order(r)``."""
    def reduce(so, r):
        reductor = cls(so.to_lti() if lti else so)
        return reductor.reduce(order(r), **options), reductor
    return reduce


SECOND, FIRST = (lambda r: r), (lambda r: 2 * r)
METHODS = {  # name -> (so, r) -> (reduced model, reductor)
    "SOBTp": _on(sobt.SOBTpReductor, SECOND), "SOBTv": _on(sobt.SOBTvReductor, SECOND),
    "SOBTpv": _on(sobt.SOBTpvReductor, SECOND), "SOBTvp": _on(sobt.SOBTvpReductor, SECOND),
    "SOBTfv": _on(sobt.SOBTfvReductor, SECOND), "SOBT": _on(sobt.SOBTReductor, SECOND),
    "SOR-IRKA": _on(SORIRKAReductor, SECOND, **SOR_IRKA),
    "SOBHI (band)": _so_bhi,
    "BT": _on(BTReductor, FIRST, lti=True),
    "IRKA": _on(IRKAReductor, FIRST, lti=True, **IRKA),
    "IRKA from BT": _bt_then(IRKAReductor),
    "TSIA from BT": _bt_then(TSIAReductor),
    "MT (eig, NM)": _on(MTReductor, FIRST, lti=True, decomposition="eig", which="NM"),
}


def _first_order(rom) -> tuple[np.ndarray, ...]:
    """Dense (E, A, B, C) of a reduced LTIModel or SecondOrderModel (module docstring)."""
    dense = lambda op: to_matrix(op, format="dense")
    if isinstance(rom, LTIModel):
        return dense(rom.E), dense(rom.A), dense(rom.B), dense(rom.C)
    m, d, k = dense(rom.M), dense(rom.E), dense(rom.K)
    eye, zero = np.eye(rom.order), np.zeros((rom.order, rom.order))
    return (np.block([[eye, zero], [zero, m]]), np.block([[zero, eye], [-k, -d]]),
            np.vstack([np.zeros_like(dense(rom.B)), dense(rom.B)]),
            np.hstack([dense(rom.Cp), dense(rom.Cv)]))


def pymor_reductions(m, d, k, b, cx, ranks, *, seed=0) -> list[dict]:
    """Every pyMOR reduction (``METHODS``) of M x'' + D x' + K x = b u, y = cx x at each r in
    ``ranks``: rows {method, r, states, offline_s, e, a, b, c} (+ iterations, converged for
    IRKA-type reductors); a reduction that raises gives a row with its ``error`` instead.

    ``seed`` seeds pyMOR's global random generator, reset before every reduction."""
    set_log_levels({"pymor": "ERROR"})
    operators = [NumpyMatrixOperator(np.asarray(x, dtype=float)) for x in (m, d, k, b, cx)]
    rows = []
    for r in ranks:
        for name, method in METHODS.items():
            row = {"method": name, "r": r, "states": 2 * r}
            try:
                with new_rng(seed):
                    so = SecondOrderModel(*operators)  # fresh: no Gramians cached
                    start = time.perf_counter()
                    rom, reductor = method(so, r)
                    row["offline_s"] = time.perf_counter() - start
                row.update(zip("eabc", _first_order(rom)))
                if getattr(reductor, "conv_crit", None):  # the IRKA-type reductors' history
                    row.update(iterations=len(reductor.conv_crit),
                               converged=bool(reductor.conv_crit[-1] < TOL))
            except Exception as error:  # a failed method is a result, not the end of the run
                row["error"] = f"{type(error).__name__}: {' '.join(str(error).split())}"
            rows.append(row)
            print(f"  pyMOR {name} r = {r}: {row.get('offline_s', 0.0):.2f} s"
                  f"{' (failed)' if 'error' in row else ''}", flush=True)
    return rows
