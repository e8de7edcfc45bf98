"""Every size and rate at which the package takes another route, in one place.

Each is decided from static structure (n, the operators' types, a damper's rate on the host),
never from free memory or tracedness. Where a limit switches between two formulations, both
sides compute the same quantity to rounding; the tests check the two sides against each other
(``test_spectral_blocks``, ``test_spectral_response_rows``, ``test_stiff``).
"""

# Undamped modes: a fixed-free chain this long or longer takes the O(n^2) bisection and twisted
# factorisations (``_chain_modes``); a shorter one the SVD of its bidiagonal factor (one LAPACK
# call compiles in a fraction of the loops). Both give every omega to a few ulps relative.
CHAIN_MODES_FROM = 256

# Damped modes: above this n the per-root (2n, n) and (2n, 2n) work is done a block of roots at
# a time (``_spectral_rows``), the same operations in another order: O(n) memory, and faster,
# since a block's rows stay in cache (``benchmarks/engine.py``, blocks rows).
BLOCK_ABOVE = 64
BLOCK_ENTRIES = 2**16  # entries of one (roots, n) block: 1 MiB complex, about an L2 cache

# Energy of a chain with dampers alone above this size: without the (n, n) modes U (128 MiB at
# 4096), from chain mode rows (``_spectral_system.uses_rows``).
ROWS_ABOVE = 4096

# Work arrays of ~2^24 entries (128-256 MB): modes per chunk when the chain's modes are combined
# without U, roots per block of a response's modal history.
CHUNK_ENTRIES = 2**24


def chunk(n: int, smallest: int) -> int:
    """Rows per chunk of an (n,)-wide work array: ``CHUNK_ENTRIES`` / n, at least ``smallest``."""
    return max(smallest, CHUNK_ENTRIES // n)


# Integrators: Dopri8 is stable for |h lambda| up to about 4-6; beyond rho T = 1e5 (some 2e4
# explicit steps) the structured implicit solver was measured faster (n = 1000: 1.0x, 10^4: 27x,
# Section 5 damper c = 1000 at DOF 7: 1.25x), below it the explicit one.
STIFF_THRESHOLD = 1e5

# ``Grid``: a damper rate c / m beyond this multiple of the highest eigenfrequency
# makes Dopri8 cost more than a matrix exponential.
STIFF_RATIO = 10.0

# ``sensitivities(mode="auto")``: forward mode up to this many parameters (4.3 s against 11.3 s
# compile, measured), reverse above.
FEW_PARAMETERS = 8
