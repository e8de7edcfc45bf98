"""Figures: 2-9 of Weber & Zastrau (2018), drawn from our own results (same quantities and
windows), a scene's figures and the damper-placement landscape.

Only matplotlib's non-interactive Agg backend is used, so figures render on a machine without a
screen. Each function writes PNGs from plain numpy arrays (``scene_figures``: from a
``SceneResult``). Every axis says its unit, or "dimensionless" (the paper's chain has m = k = 1:
times in units of sqrt(m/k), frequencies of sqrt(k/m)); panels are marked (a), (b) above
the panel; legends stand outside the data, to the right.
"""

from pathlib import Path

import numpy as np


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


TIME = "time t (dimensionless, m = k = 1)"


def _mark(axes) -> None:
    """(a), (b), ... just above the top left corner of each panel (outside the data)."""
    for k, axis in enumerate(axes):
        axis.text(0.0, 1.01, f"({chr(ord('a') + k)})", transform=axis.transAxes, va="bottom",
                  ha="left", fontweight="bold", fontsize=10)


def _legend(axis, **kwargs) -> None:
    """A legend to the right of the panel, never over the data."""
    axis.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), frameon=False,
                fontsize=kwargs.pop("fontsize", 8), **kwargs)


def _save(fig, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    _plt().close(fig)
    return path


def eigensolutions(path, eigenvalues, shapes) -> Path:
    """Fig. 2: eigenvalues lambda_l = Omega_l^2 and mode shapes u_1..u_5 (i = 0 is the support)."""
    plt = _plt()
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    l = np.arange(1, len(eigenvalues) + 1)
    left.plot(l, eigenvalues, "o-")
    left.set(xlabel="mode number l", ylabel=r"$\lambda_l = \Omega_l^2$  [k/m]",
             title=f"eigenvalues (n = {len(eigenvalues)}): $l^2$ k/m")
    i = np.arange(0, shapes.shape[1] + 1)
    for k, shape in enumerate(shapes, start=1):
        right.plot(i, np.concatenate([[0.0], shape]), "o-", ms=4, label=f"$u_{k}$")
    right.axhline(0, color="0.7", lw=0.8)
    right.set(xlabel="DOF i (0: the support)", ylabel="mode shape (dimensionless, peak 1)",
              title="mode shapes $u_1 \\ldots u_5$")
    _legend(right)
    _mark((left, right))
    return _save(fig, Path(path))


def singular_values_and_modes(path, singular_values, modes, labels, title, marks=()) -> Path:
    """Figs. 3, 5, 7: singular values (log scale) and selected POMs over the DOF index;
    ``marks``: (rank, label) pairs drawn as vertical lines on the singular values (n_red)."""
    plt = _plt()
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4))
    s = np.asarray(singular_values)
    left.semilogy(np.arange(1, len(s) + 1), np.maximum(s, 1e-300), ".", ms=3)
    for (rank, label), color in zip(marks, ("tab:red", "tab:green", "tab:purple")):
        left.axvline(rank, color=color, ls="--", lw=1, label=label)
    if marks:
        left.legend(loc="lower left", fontsize=8)
    left.set(xlabel="k", ylabel=r"$\sigma_k$ (dimensionless, m = k = 1)", title="singular values")
    i = np.arange(1, modes.shape[0] + 1)
    for label in labels:
        right.plot(i, modes[:, label - 1], lw=1, label=f"POM {label}")
    right.set(xlabel="DOF i", ylabel=r"POM $\varphi_k$ (dimensionless, unit norm)", title=title)
    _legend(right)
    _mark((left, right))
    return _save(fig, Path(path))


def histories(path, ts, displacement, velocity=None, dofs=None, title="",
              stacked: bool = False) -> Path:
    """Figs. 4 and 6: displacement (and velocity) histories of the given DOFs; ``stacked``: one
    panel per DOF (displacements only), so a small response is not hidden under a large one."""
    plt = _plt()
    labels = list(dofs if dofs is not None else range(1, displacement.shape[1] + 1))
    if stacked:
        fig, axes = plt.subplots(len(labels), 1, figsize=(10, 1.5 * len(labels) + 1),
                                 sharex=True, squeeze=False)
        for column, dof in enumerate(labels):
            axes[column, 0].plot(ts, displacement[:, column], lw=0.8, color=f"C{column}")
            axes[column, 0].set_ylabel(f"$x_{{{dof}}}$")
        axes[0, 0].set_title(title + "\ndisplacements (dimensionless, m = k = 1)")
        axes[-1, 0].set_xlabel(TIME)
        _mark(axes[:, 0])
        return _save(fig, Path(path))
    panels = 1 if velocity is None else 2
    fig, axes = plt.subplots(panels, 1, figsize=(11, 3.2 * panels), squeeze=False, sharex=True)
    for column, dof in enumerate(labels):
        axes[0, 0].plot(ts, displacement[:, column], lw=0.8, label=f"DOF {dof}")
        if velocity is not None:
            axes[1, 0].plot(ts, velocity[:, column], lw=0.8, label=f"DOF {dof}")
    axes[0, 0].set(ylabel="displacement $x_i$ (dimensionless)", title=title)
    _legend(axes[0, 0], fontsize=7, ncol=1 if len(labels) <= 12 else 2)
    if velocity is not None:
        axes[1, 0].set(ylabel="velocity $v_i$ (dimensionless)")
    axes[-1, 0].set_xlabel(TIME)
    _mark(axes[:, 0])
    return _save(fig, Path(path))


def full_versus_reduced(path, ts, full_x, full_v, red_x, red_v, dof: int, rank: int) -> Path:
    """Figs. 8-9: displacement and velocity of one DOF, full ("full") against reduced ("MOR")."""
    plt = _plt()
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    for axis, full, red, name in ((top, full_x, red_x, "displacement"),
                                  (bottom, full_v, red_v, "velocity")):
        axis.plot(ts / np.pi, full, "k-", lw=2, label="full (n = 300)")
        axis.plot(ts / np.pi, red, "r--", lw=1.5, label=f"MOR (n_red = {rank})")
        axis.set(ylabel=f"{name} of DOF {dof}\n(dimensionless)")
        _legend(axis)
    bottom.set(xlabel=r"$t / \pi$  (t dimensionless, m = k = 1)")
    top.set_title(f"DOF {dof}, full and reduced (n_red = {rank}), exact solutions")
    _mark((top, bottom))
    return _save(fig, Path(path))


def scene_figures(result, folder) -> list[Path]:
    """The figures a scene asks for (``[output] figures = true``): histories and singular values.

    ``result``: the scene's ``SceneResult`` (``run_scene``).
    """
    folder = Path(folder)
    name, ts, dofs = result.scene.name, np.asarray(result.times), list(result.dofs)
    full = result.full
    pick = [full.dofs.index(d) for d in dofs]
    written = [histories(folder / "displacement.png", ts, np.asarray(full.displacement)[:, pick],
                         dofs=dofs, title=f"{name}: full model")]
    if result.model is not None:
        reduced, rank = result.reduced, result.model.rank
        pick_r = [reduced.dofs.index(d) for d in dofs]
        written.append(histories(folder / "reduced_displacement.png", ts,
                                 np.asarray(reduced.displacement)[:, pick_r], dofs=dofs,
                                 title=f"{name}: reduced model, r = {rank}"))
        decomposition = result.model.stats.decomposition
        written.append(singular_values_and_modes(
            folder / "singular_values.png", np.asarray(decomposition.singular_values),
            np.asarray(decomposition.modes), list(range(1, min(5, rank) + 1)),
            "leading POMs"))
    return written


def placement_landscape(path, positions, coefficients, values, paths, optimum, title) -> Path:
    """The objective over (damper position, coefficient), the optimiser's paths and the optimum.

    ``values[i, j]`` at ``positions[i]``, ``coefficients[j]`` (log scale); ``paths``: a list of
    (positions, coefficients) sequences, one per start; ``optimum``: (position, coefficient).
    """
    plt = _plt()
    fig, ax = plt.subplots(figsize=(8, 5))
    v = np.log10(np.asarray(values, dtype=float))
    mesh = ax.pcolormesh(np.asarray(positions), np.asarray(coefficients), v.T, shading="nearest",
                         cmap="viridis")
    fig.colorbar(mesh, ax=ax, label=r"$\log_{10} J$ (J in the model's energy units)")
    for k, (p, c) in enumerate(paths):
        ax.plot(p, c, "-", color="C1", lw=1.2, label="optimiser paths (o: start)" if k == 0
                else None)
        ax.plot(p[:1], c[:1], "o", color="C1", ms=4)
    ax.plot([optimum[0]], [optimum[1]], "*", color="red", mec="white", ms=14,
            label="certified optimum")
    ax.set(xlabel="damper position p (DOF, 1-based)",
           ylabel="damper coefficient c (force x time / length)", yscale="log", title=title)
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.14), ncols=2, frameon=False)
    return _save(fig, Path(path))


def search_history(path, values, label: str, title: str) -> Path:
    """The criterion after each step of a full-order search (log scale): ``values`` in order,
    ``label`` the step's name ("iteration", "accepted move")."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4))
    values = np.asarray(values, dtype=float)
    ax.plot(np.arange(values.shape[0]), values, "o-", ms=4)
    ax.set(xlabel=label, ylabel="criterion (model units)", yscale="log", title=title)
    ax.grid(True, which="both", alpha=0.3)
    return _save(fig, Path(path))
