"""The actuation-consistency basis: an orthonormal basis of ``Null(J_act^T)``, kept implicit.

Actuation-consistency basis. ``N_u`` (columns of ``U`` beyond rank in a full SVD
``J_act = U S V^T``, rank by an *absolute* tolerance on the singular values, units of ``J``)
is only defined up to a rotation within ``Null(J_act^T)`` when singular values are repeated
zeros, and the box ``|N_u^T f| <= eps`` depends on that choice. :class:`ActuationNullSpace` uses
the basis LAPACK's full SVD of a tall matrix produces (a Householder QR first, then the SVD of
the small triangular factor): when ``J_act`` has full column rank it equals
``numpy.linalg.svd(J_act)[0][:, n:]`` up to column signs, which leave the symmetric box
unchanged. It is kept as Householder reflectors and applied in O(m n), never formed as an
(m, m) matrix in the control loop. The rank needs no SVD when ``J_act`` has full column rank with
room to spare (the common case): a lower bound of the smallest singular value from the QR's
triangle (:func:`~wholehand.allocation.kernels.sigma_min_lower_bound`) certifies it, and the SVD
decides otherwise.
"""

from __future__ import annotations

from typing import cast

import numpy as np
import numpy.typing as npt
from scipy.linalg import lapack

from wholehand import defaults
from wholehand.allocation.kernels import sigma_min_lower_bound

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]


RANK_MARGIN: float = 1.001
"""Full column rank is taken without the SVD when a lower bound of the smallest singular value
exceeds ``svd_tol`` by this factor, far beyond the bound's rounding (about 1e-13 relative); below
it the SVD decides, as it always did."""


class ActuationNullSpace:
    """Orthonormal basis ``N_u`` (m, m - r) of ``Null(J_act^T)``, kept implicit.

    ``N_u`` is the block of columns of ``U`` beyond the rank in a full SVD ``J_act = U S V^T``
    (see the module docstring for which SVD). Only products are formed: :meth:`project` gives
    ``N_u^T v`` and :meth:`columns` selected columns of ``N_u``.
    """

    def __init__(
        self,
        J_act: FloatArray,
        svd_tol: float = defaults.SVD_TOL,
        nonzero_cols: IntArray | None = None,
    ) -> None:
        """Args:
        J_act: (m, k) stacked point Jacobians of the actuated contacts (3 rows per contact,
            world axes) restricted to the actuated joints.
        svd_tol: Absolute tolerance on the singular values deciding the rank.
        nonzero_cols: Indices of the columns of ``J_act`` that are not all zero, if known.
        """
        m = J_act.shape[0]
        self.m = m
        """Rows of ``J_act`` (3 per actuated contact)."""
        if nonzero_cols is None:
            nonzero_cols = np.flatnonzero(np.any(J_act != 0.0, axis=0))
        cols = nonzero_cols
        k = cols.size
        self._k = k
        self._explicit: FloatArray | None = None
        self._qr: FloatArray | None = None
        self._tau: FloatArray | None = None
        self._head: FloatArray | None = None
        self._s: FloatArray | None = None
        if k == 0:
            self._s = np.zeros(0)
            self.rank = 0
            self._explicit = np.eye(m)
        elif m > k:
            # Householder QR: J_c = Q [R; 0]; SVD(J_c) = Q [U_R 0; 0 I] [S; 0] V^T.
            Jc = J_act if k == J_act.shape[1] else J_act[:, cols]
            qr, tau, _, info = lapack.dgeqrf(Jc)
            if info != 0:  # pragma: no cover - LAPACK argument error
                raise ValueError(f"dgeqrf failed with info={info}")
            self._qr, self._tau = qr, tau
            if sigma_min_lower_bound(qr, k) > svd_tol * RANK_MARGIN:
                self.rank = k  # certified full column rank: the SVD would count every value
            else:
                s = self._r_singular_values()
                r = int(np.count_nonzero(s > svd_tol))
                self.rank = r
                if r < k:
                    U_R = np.linalg.svd(np.triu(qr[:k]))[0]
                    self._head = np.ascontiguousarray(U_R[:, r:])
        else:
            U, s, _ = np.linalg.svd(J_act[:, cols], full_matrices=True)
            r = int(np.count_nonzero(s > svd_tol))
            self._s = s
            self.rank = r
            self._explicit = np.ascontiguousarray(U[:, r:])
        self.dim = m - self.rank
        """Dimension of ``Null(J_act^T)``: the number of consistency rows."""

    @property
    def singular_values(self) -> FloatArray:
        """Singular values of ``J_act``'s nonzero columns, descending (computed on first use
        when the rank was certified without them)."""
        if self._s is None:
            self._s = self._r_singular_values()
        return self._s

    def _r_singular_values(self) -> FloatArray:
        """Singular values of the QR's triangular factor (those of ``J_act``'s nonzero
        columns)."""
        assert self._qr is not None
        R = np.triu(self._qr[: self._k])
        _, s, _, info = lapack.dgesdd(R, compute_uv=0)
        if info != 0:  # pragma: no cover - no convergence
            s = np.linalg.svd(R, compute_uv=False)
        self._s = s
        return cast(FloatArray, s)

    def _apply_q(self, C: FloatArray, trans: str) -> FloatArray:
        assert self._qr is not None and self._tau is not None
        C = np.asfortranarray(C)
        out, _, info = lapack.dormqr(
            "L", trans, self._qr, self._tau, C, lwork=max(1, 64 * C.shape[1])
        )
        if info != 0:  # pragma: no cover - LAPACK argument error
            raise ValueError(f"dormqr failed with info={info}")
        return cast(FloatArray, out)

    def project(self, v: FloatArray) -> FloatArray:
        """``N_u^T v`` for (m,) ``v``: its (dim,) coordinates in the null-space basis."""
        if self._explicit is not None:
            return cast(FloatArray, self._explicit.T @ v)
        y = self._apply_q(v.reshape(-1, 1), "T")[:, 0]
        if self._head is None:
            return y[self._k :]
        return np.concatenate((self._head.T @ y[: self._k], y[self._k :]))

    def columns(self, idx: IntArray) -> FloatArray:
        """(m, len(idx)) columns ``N_u[:, idx]`` (``idx`` in ``[0, dim)``)."""
        idx = np.asarray(idx, dtype=np.intp)
        if self._explicit is not None:
            return self._explicit[:, idx]
        k = self._k
        nh = 0 if self._head is None else self._head.shape[1]
        Z = np.zeros((self.m, idx.size))
        head = idx < nh
        if head.any():
            assert self._head is not None
            Z[:k, head] = self._head[:, idx[head]]
        tail = np.flatnonzero(~head)
        Z[k + idx[tail] - nh, tail] = 1.0
        return self._apply_q(Z, "N")

    def householder(self) -> tuple[FloatArray, FloatArray] | None:
        """``(qr, tau)``: the Householder QR of ``J_act``'s nonzero columns as LAPACK's
        ``dgeqrf`` leaves it ((m, k) Fortran order, (k,)), whose ``Q``'s last ``dim`` columns
        are ``N_u`` (full column rank); None where the basis is held otherwise (rank deficient,
        or not taller than wide)."""
        if self._qr is None or self._tau is None or self._head is not None:
            return None
        return self._qr, self._tau

    def basis(self) -> FloatArray:
        """The explicit (m, dim) basis ``N_u`` (allocates (m, m); not for the control loop)."""
        return self.columns(np.arange(self.dim))


__all__ = ["ActuationNullSpace"]
