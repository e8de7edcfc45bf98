"""Scene systems: custom matrices (files and inline), branched chains and [internal_damping],
checked against matrices assembled here by hand, SciPy's eigh and Mikota's own scene."""

import numpy as np
import pytest
import scipy.linalg
import scipy.sparse

import mikota_jax as mj
from mikota_jax._io import save_matrix_market

N = 8
DOFS = np.arange(1, N + 1)
SPRINGS = N - DOFS + 1.0  # Mikota (eq. 2.3) with m = k = 1
M = np.diag(1.0 / DOFS)
K = (np.diag(SPRINGS + np.append(SPRINGS[1:], 0.0)) - np.diag(SPRINGS[1:], 1)
     - np.diag(SPRINGS[1:], -1))
D = np.zeros((N, N))
D[2, 2] = 0.5  # a grounded damper at DOF 3
DAMPER = '\n[[damper]]\ntype = "grounded"\nposition = 3\ncoefficient = 0.5\n'
REST = """
[initial]
displacement = "mode 2"
velocity = { 8 = 1.0 }

[time]
end = 1.0
step = 0.25
"""
MIKOTA = f'[chain]\ntype = "mikota"\nn = {N}\n'


def toml_list(values) -> str:
    return "[" + ", ".join(repr(float(v)) for v in values) + "]"


def displacement(result) -> np.ndarray:
    assert result.full.dofs == tuple(range(1, N + 1))
    return np.asarray(result.full.displacement)


def assemble(springs, n):
    """K from (a, b, k) springs between 0-based DOFs a and b (b = None: to the ground)."""
    stiffness = np.zeros((n, n))
    for a, b, k in springs:
        stiffness[a, a] += k
        if b is not None:
            stiffness[b, b] += k
            stiffness[a, b] -= k
            stiffness[b, a] -= k
    return stiffness


@pytest.fixture(scope="module")
def mikota_result():
    return displacement(mj.run_scene(mj.app.load_scene(MIKOTA + DAMPER + REST)))


@pytest.fixture
def files(tmp_path):
    np.savez(tmp_path / "system.npz", M=M, K=K, D=D)
    save_matrix_market(tmp_path / "m.mtx", scipy.sparse.coo_array(M))  # coordinate
    save_matrix_market(tmp_path / "d.mtx.gz", D)  # array
    scipy.sparse.save_npz(tmp_path / "k.npz", scipy.sparse.csr_array(K))
    return tmp_path


CUSTOM = {
    "npz_and_mtx": 'mass = "m.mtx"\nstiffness = "system.npz:K"\ndamping = "system.npz:D"\n',
    "inline_and_gz": (f"mass = {toml_list(1.0 / DOFS)}\n"
                      f"stiffness = [{toml_list(np.diag(K))}, {toml_list(np.diag(K, 1))}]\n"
                      'damping = "d.mtx.gz"\n'),
    "dense_mass_sparse_npz": 'mass = "system.npz:M"\nstiffness = "k.npz"\n' + DAMPER,
}


@pytest.mark.parametrize("variant", [  # one file format per default run, all under -m slow
    v if v == "npz_and_mtx" else pytest.param(v, marks=pytest.mark.slow) for v in CUSTOM])
def test_custom_matrices_from_files_reproduce_mikotas_scene(files, mikota_result, variant):
    path = files / "scene.toml"
    path.write_text('[chain]\ntype = "custom"\n' + CUSTOM[variant] + REST)
    scene = mj.app.load_scene(path)  # relative file names: next to the scene file
    mass, damping, stiffness = (np.asarray(a) for a in scene.system.dense())
    np.testing.assert_allclose(mass, M, rtol=0, atol=1e-15)
    np.testing.assert_allclose(stiffness, K, rtol=0, atol=1e-14)
    np.testing.assert_allclose(damping, D, rtol=0, atol=1e-14)
    np.testing.assert_allclose(np.asarray(scene.x0), np.asarray(mj.analytic.mode_shape(N, 2)),
                               rtol=0, atol=1e-12)  # "mode 2": eigh, normalised as eq. (2.5)
    result = mj.run_scene(scene)
    np.testing.assert_allclose(displacement(result), mikota_result, rtol=0, atol=1e-10)


def test_relative_matrix_files_of_toml_text_are_read_from_the_current_directory(
        files, monkeypatch):
    monkeypatch.chdir(files)
    text = '[chain]\ntype = "custom"\n' + CUSTOM["npz_and_mtx"] + REST
    mass, damping, stiffness = (np.asarray(a) for a in mj.app.load_scene(text).system.dense())
    np.testing.assert_array_equal(stiffness, K)
    other = files / "sub"
    other.mkdir()
    (other / "scene.toml").write_text(text)
    with pytest.raises(ValueError, match=r"\[chain\] mass: matrix file .*sub.*m\.mtx.*not exist"):
        mj.app.load_scene(other / "scene.toml")  # a scene file's names are relative to its folder


def test_inline_dense_rows_and_a_custom_chains_modes_follow_eigh():
    rows = "[" + ", ".join(toml_list(row) for row in K) + "]"
    scene = mj.app.load_scene(f'[chain]\ntype = "custom"\nmass = {toml_list(1.0 / DOFS)}\n'
                          f"stiffness = {rows}\n" + REST.replace("mode 2", "mode 5"))
    np.testing.assert_array_equal(np.asarray(scene.system.dense()[2]), K)
    np.testing.assert_allclose(np.asarray(scene.x0), np.asarray(mj.analytic.mode_shape(N, 5)),
                               rtol=0, atol=1e-12)
    chain = mj.app.load_scene('[chain]\ntype = "custom"\n'
                          f"masses = {toml_list(1.0 / DOFS)}\nsprings = {toml_list(SPRINGS)}\n"
                          + REST.replace("mode 2", "mode 7"))
    np.testing.assert_allclose(np.asarray(chain.x0), np.asarray(mj.analytic.mode_shape(N, 7)),
                               rtol=0, atol=1e-12)


BRANCHED = """
[chain]
type = "branched"
hub_mass = 3.0
hub_spring = 0.7

[[chain.branch]]
masses = [1.0, 2.0]
springs = [3.0, 4.0, 5.0]

[[chain.branch]]
masses = [0.5]
springs = [2.0, 1.5]

[initial]
displacement = "mode 1"
velocity = { 2 = 1.0 }

[time]
end = 1.0
step = 0.25
"""


def test_a_branched_scene_is_the_hand_assembled_system_and_mj_branched_chain():
    scene = mj.app.load_scene(BRANCHED)
    mass = np.diag([1.0, 2.0, 0.5, 3.0])  # DOFs: branch 1 (1, 2), branch 2 (3), the hub (4)
    stiffness = assemble([(0, None, 3.0), (0, 1, 4.0), (1, 3, 5.0), (2, None, 2.0),
                          (2, 3, 1.5), (3, None, 0.7)], 4)
    got_m, got_d, got_k = (None if a is None else np.asarray(a) for a in scene.system.dense())
    assert got_d is None
    np.testing.assert_array_equal(got_m, mass)
    np.testing.assert_allclose(got_k, stiffness, rtol=0, atol=1e-15)
    omega2, modes = scipy.linalg.eigh(stiffness, mass)
    mode = modes[:, 0] / np.max(np.abs(modes[:, 0]))
    np.testing.assert_allclose(np.asarray(scene.x0), mode * np.sign(mode[-1]), rtol=0, atol=1e-12)
    python = mj.branched_chain([np.array([1.0, 2.0]), np.array([0.5])],
                               [np.array([3.0, 4.0, 5.0]), np.array([2.0, 1.5])], 3.0, 0.7)
    reference = mj.solve(python, scene.ts, scene.x0, scene.v0, method=mj.DenseExponential())
    result = mj.run_scene(scene)
    assert result.full.dofs == (1, 2, 3, 4)
    got = np.asarray(result.full.displacement)
    np.testing.assert_allclose(got, np.asarray(reference.displacement), rtol=0, atol=1e-13)
    # x(t) = sum_l U_l (U_l^T M x0 cos(w_l t) + U_l^T M v0 sin(w_l t) / w_l): independent truth
    t, w = np.asarray(scene.ts), np.sqrt(omega2)
    a, b = modes.T @ mass @ np.asarray(scene.x0), modes.T @ mass @ np.asarray(scene.v0)
    exact = (np.cos(np.outer(t, w)) * a + np.sin(np.outer(t, w)) * (b / w)) @ modes.T
    np.testing.assert_allclose(got, exact, rtol=0, atol=1e-12)


def test_the_uniform_branched_shorthand_assembles_equal_branches():
    scene = mj.app.load_scene('[chain]\ntype = "branched"\nlengths = [2, 1]\nmass = 2.0\n'
                          "spring = 3.0\nhub_spring = 0.5\n[time]\nend = 1.0\nstep = 0.5\n")
    stiffness = assemble([(0, None, 3.0), (0, 1, 3.0), (1, 3, 3.0), (2, None, 3.0), (2, 3, 3.0),
                          (3, None, 0.5)], 4)
    mass, _, got = (None if a is None else np.asarray(a) for a in scene.system.dense())
    np.testing.assert_array_equal(mass, np.diag([2.0, 2.0, 2.0, 1.0]))  # hub_mass default 1
    np.testing.assert_allclose(got, stiffness, rtol=0, atol=1e-15)


def internal(body: str, chain: str = MIKOTA) -> str:
    return chain + "\n[internal_damping]\n" + body + "\n[time]\nend = 1.0\nstep = 0.25\n"


def modal_truth():
    omega2, modes = scipy.linalg.eigh(K, M)
    return np.sqrt(omega2), modes


def test_rayleigh_damping_is_alpha_m_plus_beta_k():
    scene = mj.app.load_scene(internal("rayleigh = [0.1, 0.02]"))
    rayleigh = scene.system.internal.rayleigh
    assert float(rayleigh.alpha) == 0.1 and float(rayleigh.beta) == 0.02
    np.testing.assert_allclose(np.asarray(scene.system.dense()[1]), 0.1 * M + 0.02 * K,
                               rtol=1e-14, atol=1e-15)


@pytest.mark.parametrize("ratios", [0.05, np.linspace(0.01, 0.08, N)])
def test_modal_damping_gives_each_mode_its_ratio(ratios):
    modal = repr(ratios) if np.ndim(ratios) == 0 else toml_list(ratios)
    scene = mj.app.load_scene(internal(f"modal = {modal}\nrayleigh = [0.0, 0.01]"))
    zeta = np.broadcast_to(ratios, (N,))
    np.testing.assert_array_equal(np.broadcast_to(scene.system.internal.modal.zeta, (N,)), zeta)
    omega, modes = modal_truth()
    in_modes = modes.T @ np.asarray(scene.system.dense()[1]) @ modes
    np.testing.assert_allclose(in_modes, np.diag(2 * zeta * omega + 0.01 * omega**2),
                               rtol=0, atol=1e-11)


def test_internal_damping_reaches_custom_and_branched_systems():
    chain = (f'[chain]\ntype = "custom"\nmass = {toml_list(1.0 / DOFS)}\n'
             f"stiffness = [{toml_list(np.diag(K))}, {toml_list(np.diag(K, 1))}]\n")
    custom = mj.app.load_scene(internal("modal = 0.1", chain))
    omega, modes = modal_truth()
    np.testing.assert_allclose(modes.T @ np.asarray(custom.system.dense()[1]) @ modes,
                               np.diag(0.2 * omega), rtol=0, atol=1e-11)
    branched = mj.app.load_scene(internal("rayleigh = [0.3, 0.0]", '[chain]\ntype = "branched"\n'
                                      "lengths = [1, 1]\n"))
    np.testing.assert_allclose(np.asarray(branched.system.dense()[1]), 0.3 * np.eye(3),
                               rtol=0, atol=1e-15)


def test_a_rayleigh_damped_first_mode_decays_as_one_damped_oscillator():
    alpha, beta = 0.2, 0.05
    text = internal(f"rayleigh = [{alpha}, {beta}]") + '[initial]\ndisplacement = "mode 1"\n'
    result = mj.run_scene(mj.app.load_scene(text))
    w = 1.0  # omega_1 = sqrt(k/m) (eq. 2.4)
    zeta = alpha / (2 * w) + beta * w / 2
    wd = w * np.sqrt(1 - zeta**2)
    t = np.asarray(result.times)
    envelope = np.exp(-zeta * w * t) * (np.cos(wd * t) + zeta * w / wd * np.sin(wd * t))
    exact = envelope[:, None] * np.asarray(mj.analytic.mode_shape(N, 1))[None, :]
    np.testing.assert_allclose(displacement(result), exact, rtol=0, atol=1e-12)


BAD_CUSTOM = '[chain]\ntype = "custom"\n'


@pytest.mark.parametrize("text, match", [
    (BAD_CUSTOM + 'masses = [1.0]\nsprings = [1.0]\nmass = [1.0]\nstiffness = [1.0]\n',
     r"\[chain\]: give either masses and springs .* not both"),
    (BAD_CUSTOM + "mass = [1.0, 2.0]\n", r"\[chain\] stiffness: is required with matrices"),
    (BAD_CUSTOM + 'mass = "nope.mtx"\nstiffness = [1.0]\n',
     r"\[chain\] mass: matrix file .*nope\.mtx.*does not exist"),
    (BAD_CUSTOM + 'mass = [1.0]\nstiffness = "system.npz:X"\n',
     r"\[chain\] stiffness: .*has no array 'X'; keys present: \['D', 'K', 'M'\]"),
    (BAD_CUSTOM + 'mass = [1.0]\nstiffness = "system.npz"\n',
     r"\[chain\] stiffness: .*holds 3 arrays.*\"file.npz:KEY\""),
    (BAD_CUSTOM + 'mass = "system.npz:M"\nstiffness = [1.0, 2.0]\n',
     r"\[chain\] stiffness: is 2 x 2, but mass is 8 x 8"),
    (BAD_CUSTOM + "mass = [1.0, 1.0]\nstiffness = [[2.0, 1.0], [1.0]]\ndamping = [[1.0], [2.0]]\n",
     r"\[chain\] damping: rows of lengths \[1, 1\] are neither"),
    (BAD_CUSTOM + "mass = [1.0, true]\nstiffness = [1.0, 1.0]\n",
     r"\[chain\] mass: must be a file"),
    (BAD_CUSTOM + "mass = [1.0, nan]\nstiffness = [1.0, 1.0]\n",
     r"\[chain\] mass: must be a file.*finite numbers only"),
    (BAD_CUSTOM + "mass = [1.0, 1.0]\nstiffness = [[2.0, 1.0], [0.0, 2.0]]\n",
     r"\[chain\]: stiffness must be symmetric"),
    (BAD_CUSTOM + "mass = [1.0, -1.0]\nstiffness = [1.0, 1.0]\n",
     r"\[chain\]: mass must be finite and positive definite"),
    (BAD_CUSTOM + "mass = [1.0, 1.0]\nstiffness = [[1.0, 2.0], [2.0, 1.0]]\n",
     r"\[chain\]: stiffness must be (finite and )?positive definite"),
    (MIKOTA + "masses = [1.0]\n",
     r"\[chain\]: unknown key\(s\) \['masses'\] for type = \"mikota\""),
    ('[chain]\ntype = "branched"\nn = 3\n',
     r"\[chain\]: unknown key\(s\) \['n'\] for type = \"branched\""),
    ('[chain]\ntype = "branched"\n', r"\[chain\]: give exactly one of \[\[chain.branch\]\]"),
    ('[chain]\ntype = "branched"\nlengths = [1]\n[[chain.branch]]\nmasses = [1.0]\n'
     "springs = [1.0, 1.0]\n", r"\[chain\]: give exactly one of"),
    ('[chain]\ntype = "branched"\nlengths = [2, 0]\n',
     r"\[chain\] lengths: must be a non-empty list of integers >= 1"),
    ('[chain]\ntype = "branched"\nlengths = [2]\nhub_mass = 0.0\n', r"\[chain\] hub_mass.*> 0"),
    ('[chain]\ntype = "branched"\nspring = 2.0\n[[chain.branch]]\nmasses = [1.0]\n'
     "springs = [1.0, 1.0]\n", r"\[chain\]: \['spring'\] belong to the shorthand lengths"),
    ('[chain]\ntype = "branched"\n[[chain.branch]]\nmasses = [1.0]\nsprings = [1.0, 1.0]\n'
     "[[chain.branch]]\nmasses = [1.0]\nsprings = [1.0]\n",
     r"\[\[chain.branch\]\] #2 springs: must have len\(masses\) \+ 1 = 2 entries"),
    ('[chain]\ntype = "branched"\n[[chain.branch]]\nmasses = [1.0]\nsprings = [1.0, 1.0]\n'
     "spring = 1.0\n", r"\[\[chain.branch\]\] #1: unknown key\(s\) \['spring'\]"),
    ('[chain]\ntype = "branched"\n[[chain.branch]]\nmasses = [0.0]\nsprings = [1.0, 1.0]\n',
     r"\[\[chain.branch\]\] #1 masses: must be a non-empty list of finite numbers > 0"),
    ('[chain]\ntype = "branched"\nlengths = [1, 1]\n[initial]\ndisplacement = "mode 4"\n',
     r"\[initial\] displacement: mode number must lie in 1\.\.3"),
    (internal(""), r"\[internal_damping\]: give rayleigh"),
    (internal("rayleigh = [0.1]"), r"\[internal_damping\] rayleigh: must be \[alpha, beta\]"),
    (internal("rayleigh = [-0.1, 0.0]"),
     r"\[internal_damping\] rayleigh: must be \[alpha, beta\], two finite"),
    (internal("modal = -0.1"), r"\[internal_damping\] modal: must be a ratio >= 0"),
    (internal('modal = "low"'), r"\[internal_damping\] modal: must be a ratio"),
    (internal("modal = [0.1, 0.1]"), r"\[internal_damping\] modal: a list must hold n = 8"),
    (internal("stiff = 1.0"), r"\[internal_damping\]: unknown key\(s\) \['stiff'\]"),
])
def test_bad_system_tables_name_the_key(files, monkeypatch, text, match):
    monkeypatch.chdir(files)
    if "[time]" not in text:
        text += "\n[time]\nend = 1.0\nstep = 0.5\n"
    with pytest.raises(ValueError, match=r"^mikota_jax: " + match):
        mj.app.load_scene(text)
