"""Chi-square quantiles for the NIS and zero-velocity tests, without importing ``scipy.stats``.

``scipy.stats`` costs about as long to import as the filter takes on an hour of 10 Hz data; the
filter needs only the quantile, which ``scipy.special`` gives directly.
"""

from __future__ import annotations

import numpy as np
from scipy.special import gammaincinv


def chi2_quantile(probability, dof):
    """Chi-square quantile: the x with P(χ²_dof ≤ x) = ``probability``.

    The same numbers, bit for bit, as ``scipy.stats.chi2.ppf(probability, dof)`` for
    0 ≤ probability ≤ 1 and dof > 0 (scipy computes it as 2·gammaincinv(dof/2, p) too); NaN
    for a probability outside [0, 1] or dof ≤ 0, as scipy gives.

    Parameters
    ----------
    probability : float or array_like
        In (0, 1).
    dof : int, float or array_like
        Degrees of freedom, > 0 (broadcast against ``probability``).

    Returns
    -------
    numpy.float64 or ndarray
    """
    p = np.asarray(probability, dtype=float)
    k = np.asarray(dof, dtype=float)
    out = np.asarray(2.0 * gammaincinv(k / 2, p), dtype=float)
    out[~((p >= 0) & (p <= 1) & (k > 0)) & np.ones(out.shape, dtype=bool)] = np.nan
    return out[()]
