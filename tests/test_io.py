"""Matrix files: load_matrix against SciPy's readers (the baseline), round trips, and one clear
error per malformed file."""

import gzip

import numpy as np
import pytest
import scipy.io
import scipy.sparse

from mikota_jax import _io
from mikota_jax._io import load_matrix, save_matrix_market


def random_sparse(n=7, density=0.4, seed=0):
    rng = np.random.default_rng(seed)
    return scipy.sparse.random_array((n, n), density=density, rng=rng, format="coo")


def dense_of(matrix):
    return matrix.toarray() if scipy.sparse.issparse(matrix) else np.asarray(matrix)


def write(path, text):
    path.write_text(text)
    return path


def test_a_dense_npz_round_trips_bit_for_bit(tmp_path):
    a = np.random.default_rng(1).standard_normal((5, 5))
    np.savez(tmp_path / "a.npz", a)
    out = load_matrix(tmp_path / "a.npz")
    assert isinstance(out, np.ndarray) and out.dtype == np.float64
    np.testing.assert_array_equal(out, a)


def test_a_key_selects_one_array_of_a_system_npz(tmp_path):
    rng = np.random.default_rng(2)
    m, k, d = (rng.standard_normal((4, 4)) for _ in range(3))
    np.savez(tmp_path / "system.npz", M=m, K=k, D=d)
    for key, truth in (("M", m), ("K", k), ("D", d)):
        np.testing.assert_array_equal(load_matrix(tmp_path / "system.npz", key=key), truth)


def test_an_npz_vector_is_read_as_a_diagonal(tmp_path):
    np.savez(tmp_path / "m.npz", mass=np.arange(1, 4))
    out = load_matrix(tmp_path / "m.npz")
    assert out.dtype == np.float64
    np.testing.assert_array_equal(out, [1.0, 2.0, 3.0])


@pytest.mark.parametrize("kind", ["csr", "csc", "coo", "dia"])
@pytest.mark.parametrize("array", [True, False])
def test_a_scipy_sparse_npz_matches_scipy_load_npz(tmp_path, kind, array):
    base = random_sparse(seed=3)
    base = scipy.sparse.coo_array(base + base.T + 10 * scipy.sparse.eye_array(7))
    matrix = base.asformat(kind) if array else scipy.sparse.coo_matrix(base).asformat(kind)
    scipy.sparse.save_npz(tmp_path / "s.npz", matrix)
    out = load_matrix(tmp_path / "s.npz")
    assert scipy.sparse.issparse(out) and out.format == "coo"
    truth = scipy.sparse.load_npz(tmp_path / "s.npz").toarray()
    np.testing.assert_array_equal(out.toarray(), truth)
    np.testing.assert_array_equal(load_matrix(tmp_path / "s.npz", dense=True), truth)


def test_a_sparse_npz_with_coords_is_read(tmp_path):
    np.savez(tmp_path / "c.npz", format=b"coo", shape=np.array([3, 3]),
             data=np.array([1.0, 2.0, 5.0]), coords=np.array([[0, 2, 1], [0, 1, 1]]))
    truth = np.zeros((3, 3))
    truth[0, 0], truth[2, 1], truth[1, 1] = 1.0, 2.0, 5.0
    np.testing.assert_array_equal(load_matrix(tmp_path / "c.npz", dense=True), truth)


@pytest.mark.parametrize("gz", [False, True])
def test_matrix_market_round_trips_dense_and_sparse_exactly(tmp_path, gz):
    suffix = ".mtx.gz" if gz else ".mtx"
    a = np.random.default_rng(4).standard_normal((6, 6)) * 10.0 ** np.arange(-3, 3)
    save_matrix_market(tmp_path / f"a{suffix}", a, comment="dense\ntwo lines")
    np.testing.assert_array_equal(load_matrix(tmp_path / f"a{suffix}"), a)
    s = random_sparse(seed=5)
    save_matrix_market(tmp_path / f"s{suffix}", s)
    out = load_matrix(tmp_path / f"s{suffix}")
    assert scipy.sparse.issparse(out)
    np.testing.assert_array_equal(out.toarray(), s.toarray())


@pytest.mark.parametrize("writer", ["dense", "sparse"])
@pytest.mark.parametrize("symmetry", ["general", "symmetric"])
@pytest.mark.parametrize("field", ["real", "integer"])
def test_load_matrix_matches_scipy_mmread(tmp_path, writer, symmetry, field):
    rng = np.random.default_rng(6)
    a = rng.integers(-9, 10, (6, 6)) * (rng.random((6, 6)) < 0.5)
    a = a + a.T if symmetry == "symmetric" else a
    a = a if field == "integer" else a * 0.37
    source = a if writer == "dense" else scipy.sparse.coo_array(a)
    scipy.io.mmwrite(tmp_path / "a.mtx", source, symmetry=symmetry, field=field)
    assert symmetry in (tmp_path / "a.mtx").read_text().splitlines()[0]
    truth = dense_of(scipy.io.mmread(tmp_path / "a.mtx"))
    np.testing.assert_array_equal(dense_of(load_matrix(tmp_path / "a.mtx")), truth)
    np.testing.assert_array_equal(truth, a)


def test_a_symmetric_coordinate_file_is_expanded_and_duplicates_summed(tmp_path):
    path = write(tmp_path / "t.mtx", "%%MatrixMarket matrix coordinate real symmetric\n"
                 "% a tridiagonal matrix, lower triangle only\n\n"
                 "3 3 6\n1 1 2.0\n2 1 -1.0\n2 2 2.0\n3 2 -1.0\n3 3 1.0\n3 3 0.5\n")
    truth = np.array([[2.0, -1.0, 0.0], [-1.0, 2.0, -1.0], [0.0, -1.0, 1.5]])
    np.testing.assert_array_equal(load_matrix(path).toarray(), truth)
    np.testing.assert_array_equal(dense_of(scipy.io.mmread(path)), truth)


def test_a_symmetric_array_file_stores_the_lower_triangle_by_columns(tmp_path):
    path = write(tmp_path / "a.mtx", "%%MatrixMarket matrix array real symmetric\n"
                 "3 3\n1\n2\n3\n4\n5\n6\n")
    truth = np.array([[1.0, 2.0, 3.0], [2.0, 4.0, 5.0], [3.0, 5.0, 6.0]])
    np.testing.assert_array_equal(load_matrix(path), truth)
    np.testing.assert_array_equal(scipy.io.mmread(path), truth)


def test_without_scipy_small_sparse_files_are_dense_and_large_ones_refused(tmp_path, monkeypatch):
    s = random_sparse(seed=7)
    save_matrix_market(tmp_path / "s.mtx", s)
    monkeypatch.setitem(__import__("sys").modules, "scipy.sparse", None)  # import fails
    out = load_matrix(tmp_path / "s.mtx")
    assert isinstance(out, np.ndarray)
    np.testing.assert_array_equal(out, s.toarray())
    monkeypatch.setattr(_io, "DENSE_LIMIT", 6)
    with pytest.raises(ValueError, match=r"s\.mtx.*sparse 7 x 7.*pip install mikota_jax\[sparse\]"):
        load_matrix(tmp_path / "s.mtx")


HEADER = "%%MatrixMarket matrix coordinate real general\n"


@pytest.mark.parametrize("name, text, match", [
    ("a.mtx", "", r"a\.mtx.*first line must be"),
    ("a.mtx", "%%MatrixMarket vector coordinate real general\n2 2 0\n", r"first line must be"),
    ("a.mtx", "%%MatrixMarket matrix banded real general\n2 2 0\n", r"format must be"),
    ("a.mtx", "%%MatrixMarket matrix coordinate complex general\n1 1 1\n1 1 1 0\n",
     r"field.*'complex'"),
    ("a.mtx", "%%MatrixMarket matrix coordinate pattern general\n1 1 1\n1 1\n",
     r"field.*'pattern'"),
    ("a.mtx", "%%MatrixMarket matrix coordinate real skew-symmetric\n1 1 0\n",
     r"symmetry.*'skew-symmetric'"),
    ("a.mtx", HEADER + "% only a comment\n", r"size line is missing"),
    ("a.mtx", HEADER + "2 2\n", r"size line must hold 3"),
    ("a.mtx", HEADER + "2 3 0\n", r"square.*\(2, 3\)"),
    ("a.mtx", HEADER + "2 2 2\n1 1 1.0\n", r"declares 2 entries.*got 1 lines"),
    ("a.mtx", HEADER + "2 2 1\n1 1\n", r"declares 1 entries.*2 numbers"),
    ("a.mtx", HEADER + "2 2 1\n3 1 1.0\n", r"indices must be integers in 1\.\.2"),
    ("a.mtx", HEADER + "2 2 1\n1 1 abc\n", r"entries must be numbers"),
    ("a.mtx", HEADER + "2 2 1\n1 1 nan\n", r"1 non-finite"),
    ("a.mtx", "%%MatrixMarket matrix array real general\n2 2\n1\n2\n3\n", r"needs 4 entries"),
    ("a.mtx", "%%MatrixMarket matrix array real general\n2 2\n1\n2\n3\ninf\n", r"non-finite"),
    ("a.txt", "1 2\n", r"a\.txt.*unknown extension"),
])
def test_a_malformed_matrix_market_file_is_named_with_the_problem(tmp_path, name, text, match):
    with pytest.raises(ValueError, match=r"^mikota_jax: matrix file .*" + match):
        load_matrix(write(tmp_path / name, text))


def test_npz_errors_name_the_file_and_the_keys(tmp_path):
    with pytest.raises(ValueError, match=r"nope\.npz.*does not exist"):
        load_matrix(tmp_path / "nope.npz")
    np.savez(tmp_path / "sys.npz", M=np.eye(2), K=np.eye(2))
    with pytest.raises(ValueError, match=r"sys\.npz.*has no array 'D'; keys present: \['K', 'M'\]"):
        load_matrix(tmp_path / "sys.npz", key="D")
    with pytest.raises(ValueError, match=r"holds 2 arrays \['K', 'M'\]; choose one"):
        load_matrix(tmp_path / "sys.npz")
    np.savez(tmp_path / "rect.npz", np.ones((2, 3)))
    with pytest.raises(ValueError, match=r"rect\.npz.*square.*\(2, 3\)"):
        load_matrix(tmp_path / "rect.npz")
    np.savez(tmp_path / "bad.npz", np.array([[1.0, np.inf], [0.0, 1.0]]))
    with pytest.raises(ValueError, match=r"bad\.npz.*1 non-finite"):
        load_matrix(tmp_path / "bad.npz")
    np.savez(tmp_path / "cplx.npz", np.eye(2) * 1j)
    with pytest.raises(ValueError, match=r"real numbers.*complex"):
        load_matrix(tmp_path / "cplx.npz")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match=r"junk\.npz.*not a readable \.npz"):
        load_matrix(tmp_path / "junk.npz")
    scipy.sparse.save_npz(tmp_path / "s.npz", scipy.sparse.csr_array(np.eye(3)))
    with pytest.raises(ValueError, match=r"one sparse matrix.*drop the key 'K'"):
        load_matrix(tmp_path / "s.npz", key="K")
    scipy.sparse.save_npz(tmp_path / "b.npz", scipy.sparse.bsr_array(np.eye(4)))
    with pytest.raises(ValueError, match=r"sparse format 'bsr' is not supported"):
        load_matrix(tmp_path / "b.npz")
    np.savez(tmp_path / "broken.npz", format=b"csr", shape=np.array([3, 3]), data=np.ones(2),
             indices=np.array([0, 1]), indptr=np.array([0, 1, 1]))
    with pytest.raises(ValueError, match=r"inconsistent csr arrays"):
        load_matrix(tmp_path / "broken.npz")
    np.savez(tmp_path / "part.npz", format=b"csr", shape=np.array([3, 3]), data=np.ones(2))
    with pytest.raises(ValueError, match=r"needs the keys \['indices', 'indptr'\]"):
        load_matrix(tmp_path / "part.npz")
    save_matrix_market(tmp_path / "a.mtx", np.eye(2))
    with pytest.raises(ValueError, match=r"one matrix; drop the key 'K'"):
        load_matrix(tmp_path / "a.mtx", key="K")


def test_a_gzip_matrix_market_file_matches_the_plain_one(tmp_path):
    text = HEADER + "2 2 2\n1 1 4.0\n2 2 9.5\n"
    with gzip.open(tmp_path / "a.mtx.gz", "wt") as handle:
        handle.write(text)
    np.testing.assert_array_equal(load_matrix(tmp_path / "a.mtx.gz", dense=True),
                                  [[4.0, 0.0], [0.0, 9.5]])
