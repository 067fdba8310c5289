"""χ² quantiles: the gates and consistency bands of Gaussian estimators.

A squared Mahalanobis distance of a ``dof``-dimensional Gaussian error is χ²(dof): the
quantiles below gate measurements (NIS), test filter consistency (NEES) and merge landmarks.
"""

from __future__ import annotations

import math


def chi2_quantile(p: float, dof: int) -> float:
    """The ``p`` quantile of the χ² distribution with ``dof`` degrees of freedom.

    Two degrees of freedom, the planar gates' case, use the closed form ``-2 ln(1 - p)``, which
    needs no scipy import; other counts use scipy's inverse regularised gamma function.

    Raises:
        ValueError: ``p`` outside [0, 1] or ``dof`` < 1.
    """
    if not 0.0 <= p <= 1.0 or dof < 1:
        raise ValueError(f"chi2_quantile needs 0 <= p <= 1 and dof >= 1, got {p}, {dof}")
    if dof == 2:
        return -2.0 * math.log1p(-p) if p < 1.0 else math.inf
    from scipy.special import gammaincinv

    return float(2.0 * gammaincinv(0.5 * dof, p))
