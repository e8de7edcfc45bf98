"""Matrices from files: NumPy ``.npz`` (dense, or ``scipy.sparse.save_npz``'s layout) and Matrix
Market ``.mtx``/``.mtx.gz`` (coordinate or array; real or integer; general or symmetric).

Both readers are pure NumPy. A dense input comes back as a float64 NumPy array; a sparse input
(a Matrix Market coordinate file, a sparse ``.npz``) as a ``scipy.sparse.coo_array`` when SciPy is
importable (``pip install mikota_jax[sparse]``), and otherwise as a dense array up to
``DENSE_LIMIT`` rows (beyond it a ``ValueError`` asks for SciPy). Either is accepted by
``mikota_jax.system``. Matrices are square; duplicate coordinate entries are summed (as SciPy
does); a symmetric Matrix Market file stores one triangle and is expanded. Every error is a
``ValueError`` naming the file and what is wrong.
"""

import gzip
from pathlib import Path

import numpy as np

from ._errors import MARK

DENSE_LIMIT = 2000  # the largest sparse file returned dense when SciPy is missing (32 MB)
_SPARSE_FORMATS = ("csr", "csc", "coo", "dia")


def _fail(path, message: str):
    raise ValueError(MARK + f"matrix file {str(path)!r}: {message}")


def _finite_float(values, path) -> np.ndarray:
    """``values`` as float64, refusing complex, non-numeric and non-finite entries."""
    values = np.asarray(values)
    if values.dtype.kind not in "biuf":
        _fail(path, f"entries must be real numbers, got dtype {values.dtype}.")
    values = values.astype(np.float64)
    if not np.all(np.isfinite(values)):
        _fail(path, f"holds {int(np.sum(~np.isfinite(values)))} non-finite entries (NaN or inf).")
    return values


def _square(shape, path) -> int:
    if len(shape) != 2 or shape[0] != shape[1] or shape[0] < 1:
        _fail(path, f"must hold a square n x n matrix (n >= 1), got shape {tuple(shape)}.")
    return int(shape[0])


def _sparse(rows, cols, values, n: int, path, dense: bool):
    """The n x n matrix with ``values`` at (``rows``, ``cols``) (0-based, duplicates summed)."""
    if not dense:
        try:
            import scipy.sparse
        except ImportError:
            if n > DENSE_LIMIT:
                _fail(path, f"is a sparse {n} x {n} matrix; without SciPy only n <= {DENSE_LIMIT} "
                      "is read (dense). Install SciPy: pip install mikota_jax[sparse].")
        else:
            matrix = scipy.sparse.coo_array((values, (rows, cols)), shape=(n, n))
            matrix.sum_duplicates()
            return matrix
    matrix = np.zeros((n, n))
    np.add.at(matrix, (rows, cols), values)
    return matrix


# --------------------------------------------------------------------------- .npz

def _indices(array, path, name: str, high: int) -> np.ndarray:
    array = np.asarray(array)
    if array.dtype.kind not in "iu" or (array.size and (array.min() < 0 or array.max() >= high)):
        _fail(path, f"sparse {name} must be integers in 0..{high - 1}.")
    return array.astype(np.int64)


def _npz_sparse(arrays, path, dense: bool):
    """A ``scipy.sparse.save_npz`` file (csr, csc, coo, dia), read with NumPy alone."""
    kind = arrays["format"].item()
    kind = kind.decode("ascii") if isinstance(kind, bytes) else str(kind)
    if kind not in _SPARSE_FORMATS:
        _fail(path, f"sparse format {kind!r} is not supported; use one of "
              f"{list(_SPARSE_FORMATS)}.")
    needed = {"csr": ("indices", "indptr"), "csc": ("indices", "indptr"), "dia": ("offsets",),
              "coo": ("coords",) if "coords" in arrays else ("row", "col")}[kind]
    missing = [k for k in ("shape", "data", *needed) if k not in arrays]
    if missing:
        _fail(path, f"a sparse {kind!r} file needs the keys {missing}; keys present: "
              f"{sorted(arrays)}.")
    n = _square(tuple(int(s) for s in np.asarray(arrays["shape"]).ravel()), path)
    data = _finite_float(arrays["data"], path)
    if kind in ("csr", "csc"):
        indptr = _indices(arrays["indptr"], path, "indptr", data.size + 1)
        indices = _indices(arrays["indices"], path, "indices", n)
        if indptr.shape != (n + 1,) or indptr[-1] != data.size or indices.size != data.size \
                or np.any(np.diff(indptr) < 0):
            _fail(path, f"inconsistent {kind} arrays: indptr must be non-decreasing, n + 1 = "
                  f"{n + 1} long and end at len(data) = {data.size}, with len(indices) = "
                  f"len(data).")
        outer = np.repeat(np.arange(n), np.diff(indptr))
        rows, cols = (outer, indices) if kind == "csr" else (indices, outer)
    elif kind == "coo":
        if "coords" in arrays:
            coords = np.asarray(arrays["coords"])
            if coords.ndim != 2 or coords.shape[0] != 2:
                _fail(path, f"coo coords must be (2, nnz), got {coords.shape}.")
            row, col = coords
        else:
            row, col = arrays["row"], arrays["col"]
        rows = _indices(row, path, "row", n)
        cols = _indices(col, path, "col", n)
        if not rows.shape == cols.shape == data.shape:
            _fail(path, f"coo row, col and data must have one length, got {rows.shape}, "
                  f"{cols.shape}, {data.shape}.")
    else:  # dia: data[k, j] sits at (j - offsets[k], j)
        offsets = np.asarray(arrays["offsets"]).astype(np.int64)
        if data.ndim != 2 or data.shape[0] != offsets.size:
            _fail(path, f"dia data must be (len(offsets), width), got {data.shape}.")
        k, cols = np.meshgrid(np.arange(offsets.size), np.arange(min(data.shape[1], n)),
                              indexing="ij")
        rows = cols - offsets[k]
        keep = (rows >= 0) & (rows < n)
        rows, cols, data = rows[keep], cols[keep], data[k[keep], cols[keep]]
    return _sparse(rows, cols, data, n, path, dense)


def _load_npz(path, key: str | None, dense: bool):
    try:
        with np.load(path, allow_pickle=False) as archive:
            arrays = {name: archive[name] for name in archive.files}
    except (OSError, ValueError) as error:  # not a zip, or a pickled (object) array
        _fail(path, f"is not a readable .npz archive ({error}).")
    if "format" in arrays and "data" in arrays:
        if key is not None:
            _fail(path, f"is one sparse matrix (scipy.sparse.save_npz layout); drop the key "
                  f"{key!r}.")
        return _npz_sparse(arrays, path, dense)
    if key is None:
        if len(arrays) != 1:
            _fail(path, f"holds {len(arrays)} arrays {sorted(arrays)}; choose one with "
                  "key=... (in a scene: \"file.npz:KEY\").")
        key = next(iter(arrays))
    elif key not in arrays:
        _fail(path, f"has no array {key!r}; keys present: {sorted(arrays)}.")
    array = arrays[key]
    if array.ndim == 1 and array.size >= 1:  # a diagonal, as mikota_jax.system reads it
        return _finite_float(array, path)
    _square(array.shape, path)
    return _finite_float(array, path)


# --------------------------------------------------------------------------- Matrix Market

def _read_text(path) -> str:
    try:
        if str(path).endswith(".gz"):
            with gzip.open(path, "rt", encoding="ascii") as handle:
                return handle.read()
        return Path(path).read_text(encoding="ascii")
    except (OSError, UnicodeDecodeError, EOFError) as error:
        _fail(path, f"cannot be read as Matrix Market text ({error}).")


def _numbers(tokens, path, what: str) -> np.ndarray:
    try:
        return np.array(tokens, dtype=np.float64)
    except ValueError:
        _fail(path, f"{what} must be numbers.")


def _load_mtx(path, dense: bool):
    lines = _read_text(path).splitlines()
    words = lines[0].lower().split() if lines else []
    if len(words) != 5 or words[0] != "%%matrixmarket" or words[1] != "matrix":
        _fail(path, "the first line must be '%%MatrixMarket matrix <coordinate|array> "
              f"<real|integer> <general|symmetric>', got {lines[0] if lines else ''!r}.")
    layout, field, symmetry = words[2:]
    if layout not in ("coordinate", "array"):
        _fail(path, f"format must be 'coordinate' or 'array', got {layout!r}.")
    if field not in ("real", "double", "integer"):
        _fail(path, f"field must be 'real' or 'integer', got {field!r} (a system matrix holds "
              "real values; 'pattern' has none, 'complex' is not supported).")
    if symmetry not in ("general", "symmetric"):
        _fail(path, f"symmetry must be 'general' or 'symmetric', got {symmetry!r} (a mass, "
              "stiffness or damping matrix is symmetric).")
    body = [line for line in lines[1:] if line.strip() and not line.lstrip().startswith("%")]
    if not body:
        _fail(path, "the size line is missing.")
    size = _numbers(body[0].split(), path, "the size line's entries")
    expected = 3 if layout == "coordinate" else 2
    if size.size != expected or np.any(size != np.round(size)) or np.any(size < 0):
        _fail(path, f"the size line must hold {expected} non-negative integers "
              f"({'rows cols entries' if expected == 3 else 'rows cols'}), got {body[0]!r}.")
    n = _square(tuple(int(s) for s in size[:2]), path)
    tokens = " ".join(body[1:]).split()
    if layout == "array":
        count = n * (n + 1) // 2 if symmetry == "symmetric" else n * n
        if len(tokens) != count:
            _fail(path, f"an {symmetry} {n} x {n} array needs {count} entries, got "
                  f"{len(tokens)}.")
        values = _finite_float(_numbers(tokens, path, "entries"), path)
        if symmetry == "general":
            return values.reshape(n, n, order="F")  # column-major, as the format stores it
        cols, rows = np.triu_indices(n)  # the lower triangle, column by column
        matrix = np.zeros((n, n))
        matrix[rows, cols] = values
        matrix[cols, rows] = values
        return matrix
    count = int(size[2])
    if len(body) - 1 != count or len(tokens) != 3 * count:
        _fail(path, f"declares {count} entries of 'row col value', got {len(body) - 1} lines "
              f"holding {len(tokens)} numbers.")
    table = _numbers(tokens, path, "entries").reshape(count, 3)
    index = table[:, :2]
    if np.any(index != np.round(index)) or np.any(index < 1) or np.any(index > n):
        _fail(path, f"row and column indices must be integers in 1..{n}.")
    rows, cols = index.T.astype(np.int64) - 1
    values = _finite_float(table[:, 2], path)
    if symmetry == "symmetric":  # one triangle stored: mirror the off-diagonal entries
        off = rows != cols
        rows, cols = np.concatenate([rows, cols[off]]), np.concatenate([cols, rows[off]])
        values = np.concatenate([values, values[off]])
    return _sparse(rows, cols, values, n, path, dense)


# --------------------------------------------------------------------------- public

def load_matrix(path: str | Path, key: str | None = None, *, dense: bool = False):
    """Read a square matrix from ``.npz``, ``.mtx`` or ``.mtx.gz`` (see the module docstring).

    ``key`` picks one array of an ``.npz`` holding several (``load_matrix("system.npz", "K")``).
    Returns a float64 (n, n) NumPy array (a 1-D array in an ``.npz`` is returned as is: a
    diagonal), or for sparse files a ``scipy.sparse.coo_array`` (dense without SciPy, for
    n <= ``DENSE_LIMIT``); ``dense=True`` always returns a NumPy array.
    """
    path = Path(path)
    if path.is_dir():
        _fail(path, "is a directory, not a matrix file.")
    if not path.is_file():
        _fail(path, "does not exist.")
    name = path.name.lower()
    if name.endswith(".npz"):
        return _load_npz(path, key, dense)
    if name.endswith((".mtx", ".mtx.gz")):
        if key is not None:
            _fail(path, f"a Matrix Market file holds one matrix; drop the key {key!r}.")
        return _load_mtx(path, dense)
    _fail(path, "has an unknown extension; use .npz, .mtx or .mtx.gz.")


def save_matrix_market(path: str | Path, matrix, comment: str = "") -> None:
    """Write ``matrix`` as Matrix Market: a dense array in 'array' format, a SciPy sparse matrix
    in 'coordinate' format (both 'real general', 17 significant digits: ``load_matrix`` reads
    back the same float64 values). A ``.gz`` suffix compresses."""
    sparse = hasattr(matrix, "tocoo")
    array = matrix.tocoo() if sparse else np.asarray(matrix)
    if len(array.shape) != 2:
        raise ValueError(MARK + f"matrix must be 2-d, got shape {array.shape}.")
    values = np.asarray(array.data if sparse else array)
    if values.dtype.kind not in "biuf" or not np.all(np.isfinite(values)):
        raise ValueError(MARK + "matrix must hold finite real numbers.")
    rows, cols = array.shape
    header = [f"%%MatrixMarket matrix {'coordinate' if sparse else 'array'} real general"]
    header += [f"% {line}" for line in comment.splitlines()]
    if sparse:
        header.append(f"{rows} {cols} {array.nnz}")
        body = [f"{i + 1} {j + 1} {v:.17g}" for i, j, v in
                zip(array.row.tolist(), array.col.tolist(), values.astype(float).tolist())]
    else:
        header.append(f"{rows} {cols}")
        body = [f"{v:.17g}" for v in values.astype(float).ravel(order="F").tolist()]
    text = "\n".join(header + body) + "\n"
    if str(path).endswith(".gz"):
        with gzip.open(path, "wt", encoding="ascii") as handle:
            handle.write(text)
    else:
        Path(path).write_text(text, encoding="ascii")
