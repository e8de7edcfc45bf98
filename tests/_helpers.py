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


def mp_eigen_energy(system, horizon, x0, v0, dps=60, as_float=True):
    """int_0^T of the physical energy, by mpmath's eigen-expansion of the first-order system at
    ``dps`` digits (about dps - 10 digits right for a diagonalisable system whose eigenvector
    matrix has condition number below 1e10; not for a defective or near-defective one); an
    mpmath number with ``as_float=False`` (for differences of it)."""
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
        value = mp.re(total) / 2
        return float(value) if as_float else value


def mp_first_order(m, d, k, dps, scale=1):
    """The physical first-order matrix [[0, I], [-M^-1 K, -M^-1 scale D]] in mpmath at ``dps``
    (``scale`` an mpmath number: a damper coefficient set beyond float64, for differences; ``d``
    may be an mpmath matrix itself)."""
    import mpmath as mp

    n = m.shape[0]
    with mp.workdps(dps):
        a = mp.zeros(2 * n, 2 * n)
        for i in range(n):
            a[i, n + i] = 1
            for j in range(n):
                a[n + i, j] = -mp.mpf(float(k[i, j])) / mp.mpf(float(m[i, i]))
                dij = d[i, j] if isinstance(d, mp.matrix) else mp.mpf(float(d[i, j]))
                a[n + i, n + j] = -scale * dij / mp.mpf(float(m[i, i]))
        return a


def mp_truths(matrices, horizon, x0, v0, ts, dps=80, scale=1, exact=False):
    """(J, trace X, x(ts)) of M x'' + D x' + K x = 0 (M diagonal) from mpmath's eigen-expansion
    at ``dps`` digits (D times the mpmath number ``scale``): J = int_0^T (x'Kx + v'Mv) / 2 dt;
    trace X of ``total_average_energy`` (A^T X + X A = -I in the scaled modal coordinates
    (Omega eta, eta')); x (len(ts), n).

    Near critical damping the expansion's coefficients grow like 1 / separation: at a relative
    distance delta from a double root the separation is ~sqrt(delta) and ~|log10 delta| / 2
    digits are lost, so at 80 digits (delta >= 1e-17) the truths keep more than 60. An exactly
    defective system (mpmath's eig fails there) needs another truth. ``exact``: J and the trace
    as mpmath numbers (for central differences beyond float64)."""
    import mpmath as mp

    m, d, k = (a if isinstance(a, mp.matrix) else np.asarray(a, dtype=float) for a in matrices)
    n = m.shape[0]
    with mp.workdps(dps):
        a = mp_first_order(m, d, k, dps, scale)
        lam, v = mp.eig(a)
        y = mp.lu_solve(v, mp.matrix([float(x) for x in x0] + [float(x) for x in v0]))
        weight = mp.zeros(2 * n, 2 * n)
        for i in range(n):
            for j in range(n):
                weight[i, j] = mp.mpf(float(k[i, j]))
            weight[n + i, n + i] = mp.mpf(float(m[i, i]))
        gram = v.transpose_conj() * weight * v
        energy = mp.mpf(0)
        for i in range(2 * n):
            for j in range(2 * n):
                s = mp.conj(lam[i]) + lam[j]
                energy += mp.conj(y[i]) * gram[i, j] * mp.expm1(s * horizon) / s * y[j]
        xs = []
        for t in ts:
            state = v * mp.matrix([y[i] * mp.exp(lam[i] * t) for i in range(2 * n)])
            xs.append([float(mp.re(state[i])) for i in range(n)])
        # trace X = int_0^inf |exp(A_s t)|_F^2 dt for A_s = S A S^-1, any S with S^T S = W =
        # blockdiag(K, M) (|z|^2 = x'Kx + v'Mv, as the scaled modal coordinates): the trace is
        # tr(exp(A^T t) W exp(A t) W^-1) integrated, sum_ij (V^H W V)_ij (V^-1 W^-1 V^-H)_ji /
        # -(conj(lam_i) + lam_j)
        vinv = v**-1
        inner = vinv * weight**-1 * vinv.transpose_conj()
        trace = mp.mpf(0)
        for i in range(2 * n):
            for j in range(2 * n):
                trace += gram[i, j] * inner[j, i] / -(mp.conj(lam[i]) + lam[j])
        if exact:
            return mp.re(energy) / 2, mp.re(trace), np.array(xs)
        return float(mp.re(energy) / 2), float(mp.re(trace)), np.array(xs)
