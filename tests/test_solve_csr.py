"""The compiled CSR passes of the solves against SciPy's indexing and products."""

import numpy as np
import pytest
import scipy.sparse as sp

from selfillum.solve.csr import column_blocks, identity_minus


def _random_csr(rng, n, m, density, dtype=np.int32):
    A = sp.random(n, m, density=density, format="csr", random_state=rng)
    A.indices = A.indices.astype(dtype)
    A.indptr = A.indptr.astype(dtype)
    return A


@pytest.mark.parametrize("dtype", [np.int32, np.int64])
def test_column_blocks_match_fancy_indexing(dtype):
    rng = np.random.default_rng(1)
    A = _random_csr(rng, 500, 400, 0.02, dtype)
    groups = rng.integers(-1, 3, 400)
    rows = rng.permutation(500)[:170]
    blocks = column_blocks(A, rows, groups, 3)
    for g, B in enumerate(blocks):
        ref = A[rows][:, np.flatnonzero(groups == g)]
        assert B.shape == ref.shape
        np.testing.assert_array_equal(B.toarray(), ref.toarray())
        assert B.has_sorted_indices or B.nnz == 0
    every = column_blocks(A, None, np.zeros(400, int), 1)[0]
    np.testing.assert_array_equal(every.toarray(), A.toarray())
    # unsorted indices and a duplicate entry: summed, as SciPy's canonical form
    U = sp.csr_matrix(([1.0, 2.0, 3.0], [2, 0, 2], [0, 3, 3]), shape=(2, 3))
    got = column_blocks(U, [0, 1], np.array([0, -1, 0]), 1)[0]
    np.testing.assert_array_equal(got.toarray(), [[2.0, 4.0], [0.0, 0.0]])
    with pytest.raises(ValueError, match="groups"):
        column_blocks(A, None, groups[:10], 3)


def test_identity_minus_matches_scipy():
    rng = np.random.default_rng(2)
    A = _random_csr(rng, 300, 300, 0.03).tolil()
    A[7, 7] = 0.25  # a stored diagonal entry
    A[9, :] = 0
    A[9, 299] = 0.5  # a row whose only entry is right of the diagonal
    A = A.tocsr()
    s = rng.uniform(0, 0.9, 300)
    s[11] = 0.0  # a row scaled to nothing: no off-diagonal entry stored
    M = identity_minus(A, s)
    ref = (sp.identity(300, format="csr") - sp.diags(s) @ A).tocsr()
    np.testing.assert_allclose(M.toarray(), ref.toarray(), rtol=0, atol=1e-15)
    assert M.has_sorted_indices
    np.testing.assert_array_equal(np.diff(M.indptr), np.diff(ref.indptr))
