"""kernels.jit: calls between kernels are typed without literal constants (first-compile
time, issue 19), and a call that needs a literal still compiles."""

from __future__ import annotations

import numpy as np
import pytest
from numba.core.caching import NullCache

from vrsim_cli.kernels.jit import JIT_DISABLED, kernel

pytestmark = pytest.mark.skipif(JIT_DISABLED, reason="typing only happens with the JIT on")

COL_A, COL_B, COL_C = 0, 3, 6  # column constants, as the kernels' K_N, K_T1, ...


@kernel
def _put3(K, i, c, v):
    K[i, c] = v[0]
    K[i, c + 1] = v[1]
    K[i, c + 2] = v[2]


@kernel
def _fill(K):
    for i in range(K.shape[0]):
        _put3(K, i, COL_A, (1.0, 2.0, 3.0))
        _put3(K, i, COL_B, (4.0, 5.0, 6.0))
        _put3(K, i, COL_C, (7.0, 8.0, 9.0))


@kernel
def _pick(t, j):
    return t[j]


@kernel
def _first_of_mixed(x):
    return _pick((x, 2), 0)  # an index into a (float, int) tuple must be a literal


# Typed afresh in every run: a caller loaded from the disk cache (a second run of this
# file) never types its callees, and the signatures checked below stay empty.
for _dispatcher in (_put3, _fill, _pick, _first_of_mixed):
    _dispatcher._cache = NullCache()


def test_a_helper_called_with_three_constants_compiles_once():
    K = np.zeros((4, 9))
    _fill(K)
    assert np.array_equal(K, np.tile(np.arange(1.0, 10.0), (4, 1)))
    # numba's default: one specialisation per constant (Literal[int](0), (3), (6))
    assert len(_put3.signatures) == 1, _put3.signatures
    assert "Literal" not in str(_put3.signatures[0])


def test_a_call_that_needs_the_literal_still_types():
    assert _first_of_mixed(2.5) == 2.5
    assert any("Literal" in str(s) for s in _pick.signatures)
