"""3 x 3 symmetric positive definite algebra on Python floats: at this size LAPACK's and NumPy's call
costs exceed the arithmetic (a station's 3 x 3 normal equations, a covariance's positivity test)."""

from __future__ import annotations

import math


def chol3(a00: float, a10: float, a20: float, a11: float, a21: float, a22: float) -> tuple[float, ...] | None:
    """Lower Cholesky factor ``(l00, l10, l20, l11, l21, l22)`` of the symmetric 3 x 3 with lower triangle
    ``a``, in ``potrf``'s order of operations; None where a pivot is not positive (NaN included)."""
    if not a00 > 0.0:
        return None
    l00 = math.sqrt(a00)
    l10, l20 = a10 / l00, a20 / l00
    d1 = a11 - l10 * l10
    if not d1 > 0.0:
        return None
    l11 = math.sqrt(d1)
    l21 = (a21 - l20 * l10) / l11
    d2 = a22 - l20 * l20 - l21 * l21
    if not d2 > 0.0:
        return None
    return l00, l10, l20, l11, l21, math.sqrt(d2)


def spd_solve3(A: list, b: list) -> list[float] | None:
    """``A^-1 b`` for ``A`` (3, 3) and ``b`` (3,) as lists: ``A = L L^T`` from ``A``'s lower triangle
    (:func:`chol3`), then ``L y = b`` and ``L^T x = y``. None unless ``A`` is positive definite with a
    finite factor."""
    (a00, _, _), (a10, a11, _), (a20, a21, a22) = A
    f = chol3(a00, a10, a20, a11, a21, a22)
    if f is None or not math.isfinite(f[5]):
        return None
    l00, l10, l20, l11, l21, l22 = f
    b0, b1, b2 = b
    y0 = b0 / l00
    y1 = (b1 - l10 * y0) / l11
    y2 = (b2 - l20 * y0 - l21 * y1) / l22
    x2 = y2 / l22
    x1 = (y1 - l21 * x2) / l11
    return [(y0 - l10 * x1 - l20 * x2) / l00, x1, x2]
