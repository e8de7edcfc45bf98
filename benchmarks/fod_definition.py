"""Why FastOptimalDamping.jl's trace is 4.4e-4 below ours at the same viscosities: coordinates.

Both solve a Lyapunov equation for the same damped system (FastOptimalDamping.jl's small example,
``spectral_objectives.fod_system``: n = 801, internal damping Gamma = 0.02 Omega, s = 27) and take
the trace of X over the s lowest modes; the trace depends on the coordinates it is taken in.

* ours (``total_average_energy``): X for A^T X + X A = -Z with A in the scaled modal coordinates
  z = (Omega eta, eta'): X is the energy over the unit initial states of the s lowest modes
  (Veselic; the energy norm is the Euclidean one there);
* theirs (``ChangeOfBasis`` in ``src/DampedSystem.jl``, ``traceX``): each mode's 2 x 2 block
  [0 omega; -omega -gamma] is diagonalised first by its eigenvectors Q_k scaled so that
  Q_k^T diag(1, -1) Q_k = diag(1, -1); A_0 = diag(Xi) + Q^T [0 0; 0 U^T D U] Q and
  A_0 X + X A_0^H = -G_0 G_0^T with G_0 selecting the s lowest modes' two eigen-coordinates.

Q is J-orthogonal but not orthogonal, so the two traces differ at order (gamma / omega)^2 = 4e-4.
This script computes both, dense (scipy's Bartels-Stewart; about a minute per solve at n = 801),
at their start [100, 100, 100] and at their printed optimum, next to the values their
``src/ResultsSmall`` prints (86769.14682911945 and 66434.85914071581): theirs is reproduced, and
ours agrees with ``total_average_energy``.

Run: ``OPENBLAS_NUM_THREADS=1 python benchmarks/fod_definition.py [--quick]`` (``--quick``: two
chains of 100, no published value to compare). Writes ``results/fod_definition[_quick].json``.
"""

# _common first: it sets OPENBLAS_NUM_THREADS before jax and numpy load.
from _common import parse_args, print_table, write_json  # noqa: I001

import numpy as np
import scipy.linalg as sl
from spectral_objectives import fod_system, two_chains

import mikota_jax as mj

NAME = "fod_definition"
LOWEST = 27
# (DOF 50, relative (550, 520), DOF 120), as fod_system takes them, and the printed traces
POINTS = {"start": ((100.0, 100.0, 100.0), 86769.14682911945),
          "published optimum": ((561.3423561622229, 651.7892318332947, 310.62572129205705),
                                66434.85914071581)}


def modal(n1):
    masses, k = two_chains(n1)
    scale = 1 / np.sqrt(masses)
    omega2, q = np.linalg.eigh(k * scale[:, None] * scale[None, :])
    return np.sqrt(omega2), q * scale[:, None]


def damper_rows(n1):
    at = lambda dof: dof * n1 // 400  # noqa: E731
    n = 2 * n1 + 1
    rows = np.zeros((3, n))
    rows[0, at(50) - 1] = 1.0
    rows[1, at(550) - 1], rows[1, at(520) - 1] = 1.0, -1.0
    rows[2, at(120) - 1] = 1.0
    return rows


def their_trace(omega, phi, rows, d, s):
    """FastOptimalDamping.jl's definition, dense."""
    n = omega.shape[0]
    gamma = 0.02 * omega
    xi = np.zeros(2 * n, complex)
    q = np.zeros((2 * n, 2 * n), complex)
    j_form = np.diag([1.0, -1.0])
    for k in range(n):
        values, vectors = sl.eig(np.array([[0.0, omega[k]], [omega[k], gamma[k]]]), j_form)
        scale = np.diag(vectors.T @ j_form @ vectors).astype(complex)
        xi[[k, n + k]] = values
        q[np.ix_([k, n + k], [k, n + k])] = vectors / np.sqrt(scale)[None, :]
    ep = rows @ phi
    block = np.zeros((2 * n, 2 * n))
    block[n:, n:] = ep.T @ np.diag(d) @ ep
    a0 = np.diag(xi) + q.T @ block @ q
    g = np.zeros((2 * n, 2 * s))
    g[:s, :s], g[n:n + s, s:] = np.eye(s), np.eye(s)
    return float(np.real(np.trace(sl.solve_continuous_lyapunov(a0, -g @ g.T))))


def our_trace_dense(omega, phi, rows, d, s):
    """Ours, dense: scaled modal coordinates."""
    n = omega.shape[0]
    ep = rows @ phi
    a = np.block([[np.zeros((n, n)), np.diag(omega)],
                  [-np.diag(omega), -np.diag(0.02 * omega) - ep.T @ np.diag(d) @ ep]])
    z = np.diag(np.concatenate([np.arange(n) < s, np.arange(n) < s]).astype(float))
    return float(np.trace(sl.solve_continuous_lyapunov(a.T, -z)))


def main(argv=None):
    args = parse_args(__doc__, argv)
    n1 = 100 if args.quick else 400
    omega, phi = modal(n1)
    rows_of = damper_rows(n1)
    rows, data = [], {}
    for name, (d, printed) in POINTS.items():
        theirs = their_trace(omega, phi, rows_of, np.asarray(d), LOWEST)
        ours_dense = our_trace_dense(omega, phi, rows_of, np.asarray(d), LOWEST)
        ours = float(mj.AverageEnergy(lowest=LOWEST)(fod_system(n1, d)))
        row = dict(point=name, printed=None if args.quick else printed, theirs=theirs,
                   ours=ours, ours_dense=ours_dense, difference=theirs / ours - 1)
        rows.append(row)
        data[name] = dict(viscosities_50_relative_120=list(d), **row)
        print(f"{name}: their definition {theirs:.12g} (printed {printed:.12g}), ours "
              f"{ours:.12g} (dense {ours_dense:.12g}), theirs / ours - 1 = "
              f"{theirs / ours - 1:+.2e}", flush=True)
    print_table(rows, [("point", "viscosities", "s"), ("printed", "printed by FOD.jl", ".12g"),
                       ("theirs", "their definition, dense", ".12g"),
                       ("ours", "total_average_energy", ".12g"),
                       ("ours_dense", "ours, dense", ".12g"),
                       ("difference", "theirs / ours - 1", ".2e")])
    write_json(NAME, args.quick, dict(n=2 * n1 + 1, lowest=LOWEST, points=data))


if __name__ == "__main__":
    main()
