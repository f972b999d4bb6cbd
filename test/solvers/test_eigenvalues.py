"""The Floquet multipliers' eigenvalue call: LAPACK's balancing and
Hessenberg reduction, then the package's compiled double-shift QR (``francis_qr``): complex pairs
laid out as LAPACK does, against ``numpy.linalg.eigvals`` on a sweep's monodromies (on random and
hard matrices: test_kernel_parity.py); the fall-back on ``dgeev`` where the QR iteration does not
converge; numpy's contract kept."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.linalg.lapack import dgeev
from support.kernel_cases import eigen_matrices, eigenvalues_of

from dmf_sim.solvers.francis_qr import hessenberg_eigenvalues
from dmf_sim.solvers.kernel_registry import KERNELS
from dmf_sim.solvers.lapack_kernel import dgeev_into
from dmf_sim.solvers.stability import eigenvalues

REPO = Path(__file__).resolve().parents[2]
REL_TOL = next(k.rel_tol for k in KERNELS if k.case == 'eigenvalues')
"""The registry's tolerance of the eigenvalue call: distance to the nearest reference eigenvalue
over the largest modulus."""


@pytest.mark.parametrize('k', range(len(eigen_matrices())))
def test_complex_pairs_are_laid_out_as_lapack_does(k):
    """As many real eigenvalues as numpy finds, and each complex pair as LAPACK gives it: the
    positive imaginary part first, then its conjugate (the values against numpy's:
    test_kernel_parity.py)."""
    wr, wi = eigenvalues_of(eigen_matrices()[k])
    i = 0
    while i < len(wi):
        if wi[i] != 0.0:
            assert wi[i] > 0.0 and wi[i + 1] == -wi[i] and wr[i + 1] == wr[i]
            i += 2
        else:
            i += 1


def test_known_spectrum_exactly_where_the_matrix_is_triangular():
    X = np.triu(np.arange(1.0, 26.0).reshape(5, 5))
    wr, wi = eigenvalues_of(X)
    assert not wi.any()
    assert sorted(wr) == sorted(np.diag(X))


def test_qr_that_does_not_converge_falls_back_on_dgeev():
    """With no iteration allowed the QR stage reports the eigenvalue it could not find, and the
    call gives what LAPACK's dgeev gives (the same bits)."""
    rng = np.random.default_rng(5)
    X = rng.standard_normal((10, 10))
    h = np.triu(X, -1)
    assert hessenberg_eigenvalues(h.copy(), np.empty(10), np.empty(10), 0) > 0
    wr, wi = eigenvalues_of(X, max_iter=0)
    ref_wr, ref_wi, _, _, info = dgeev(X, compute_vl=0, compute_vr=0)
    assert info == 0
    assert np.array_equal(wr, ref_wr) and np.array_equal(wi, ref_wi)
    wr2, wi2 = np.empty(10), np.empty(10)
    assert dgeev_into(X, wr2, wi2) == 0
    assert np.array_equal(wr2, ref_wr) and np.array_equal(wi2, ref_wi)


def test_eigenvalues_keep_numpys_contract():
    """``stability.eigenvalues``: complex where any eigenvalue is complex, real where all are
    real, LinAlgError for an inf or NaN; the values of the compiled call."""
    rng = np.random.default_rng(7)
    for n in (2, 7, 32):
        X = rng.standard_normal((n, n))
        ref = np.linalg.eigvals(X)
        mu = eigenvalues(X.copy())
        assert mu.dtype == ref.dtype
        wr, wi = eigenvalues_of(X)
        assert np.array_equal(mu, wr + 1j * wi)
    S = rng.standard_normal((6, 6))
    sym = S + S.T
    assert eigenvalues(sym.copy()).dtype == np.float64
    sym[2, 3] = np.nan
    with pytest.raises(np.linalg.LinAlgError, match='infs or NaNs'):
        eigenvalues(sym)


@pytest.mark.slow
def test_bench_eigen_quick_on_a_sweeps_monodromies():
    """The benchmark's small run: the monodromies a sweep meets, both calls within the tolerance
    of numpy's eigvals, the figures as the last JSON line."""
    out = subprocess.run([sys.executable, str(REPO / 'benchmarks' / 'bench_eigen.py'),
                          '--quick'], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    data = json.loads(out.stdout.strip().splitlines()[-1])
    assert data['matrices'] > 0 and data['size'] == 32
    assert data['max_rel_diff_package'] <= REL_TOL
    assert data['max_rel_diff_dgeev'] <= REL_TOL
    assert data['us_per_matrix_package_min'] > 0 and data['ratio_median'] > 0
    bad = subprocess.run([sys.executable, str(REPO / 'benchmarks' / 'bench_eigen.py'),
                          '--repeat', '0'], capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and '--repeat 0' in bad.stderr
    assert 'Traceback' not in bad.stderr
