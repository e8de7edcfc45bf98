"""Helpers shared by test modules (imported as ``_helpers``; pytest puts tests/ on sys.path)."""

import numpy as np


def orthonormal(rows, cols, seed):
    """A random (rows, cols) matrix with orthonormal columns."""
    q, _ = np.linalg.qr(np.random.default_rng(seed).standard_normal((rows, cols)))
    return q


def sign_rule(modes):
    """The package's documented convention: each column's largest-magnitude entry is positive."""
    index = np.argmax(np.abs(modes), axis=0)
    return modes * np.sign(modes[index, np.arange(modes.shape[1])])[None, :]
