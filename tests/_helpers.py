"""Helpers shared by test modules (imported as ``_helpers``; pytest puts tests/ on sys.path)."""

import numpy as np
import scipy.linalg as sl


def orthonormal(rows, cols, seed):
    """A random (rows, cols) matrix with orthonormal columns."""
    q, _ = np.linalg.qr(np.random.default_rng(seed).standard_normal((rows, cols)))
    return q


def sign_rule(modes):
    """The package's documented convention: each column's largest-magnitude entry is positive."""
    index = np.argmax(np.abs(modes), axis=0)
    return modes * np.sign(modes[index, np.arange(modes.shape[1])])[None, :]


def lyapunov_trace(system, lowest=None):
    """scipy's Bartels-Stewart on A = [[0, Omega], [-Omega, -U^T D U]] from scipy's eigh, with
    one step of iterative refinement (a mode decaying at 7e-7 left the raw solution 5e-9 off)."""
    m, d, k = (np.asarray(a) for a in system.dense())
    omega2, u = sl.eigh(k, m)
    omega = np.sqrt(omega2)
    n = omega.shape[0]
    a = np.block([[np.zeros((n, n)), np.diag(omega)], [-np.diag(omega), -u.T @ d @ u]])
    select = np.ones(n) if lowest is None else (np.arange(n) < lowest).astype(float)
    z = np.diag(np.concatenate([select, select]))
    x = sl.solve_continuous_lyapunov(a.T, -z)
    x = x + sl.solve_continuous_lyapunov(a.T, -(a.T @ x + x @ a + z))
    return np.trace(x)


def mp_eigen_energy(system, horizon, x0, v0, dps=60):
    """int_0^T of the physical energy, by mpmath's eigen-expansion of the first-order system at
    ``dps`` digits (about dps - 10 digits right for a diagonalisable system whose eigenvector
    matrix has condition number below 1e10; not for a defective or near-defective one)."""
    import mpmath as mp

    m, d, k = (np.asarray(a, dtype=float) for a in system.dense())
    n = m.shape[0]
    with mp.workdps(dps):
        mm, dd, kk = (mp.matrix(a.tolist()) for a in (m, d, k))
        minv = mm**-1
        a = mp.zeros(2 * n, 2 * n)
        for i in range(n):
            a[i, n + i] = 1
        lower_k, lower_d = -minv * kk, -minv * dd
        for i in range(n):
            for j in range(n):
                a[n + i, j], a[n + i, n + j] = lower_k[i, j], lower_d[i, j]
        lam, v = mp.eig(a)
        y = mp.lu_solve(v, mp.matrix([float(x) for x in x0] + [float(x) for x in v0]))
        weight = mp.zeros(2 * n, 2 * n)
        for i in range(n):
            for j in range(n):
                weight[i, j], weight[n + i, n + j] = kk[i, j], mm[i, j]
        gram = v.transpose_conj() * weight * v
        total = mp.mpf(0)
        for i in range(2 * n):
            for j in range(2 * n):
                s = mp.conj(lam[i]) + lam[j]
                integral = horizon if s == 0 else mp.expm1(s * horizon) / s
                total += mp.conj(y[i]) * gram[i, j] * integral * y[j]
        return float(mp.re(total) / 2)
