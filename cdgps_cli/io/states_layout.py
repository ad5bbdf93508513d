"""What STATES.mcap holds and the options that choose it (no numerics: the CLI reads the defaults).

Beside its Foxglove JSON channels (:mod:`cdgps_cli.io.states`), a STATES.mcap carries every epoch
of every series as packed arrays (:mod:`cdgps_cli.io.packed_arrays`), the arrays cdgps itself
reads:

* ``arrays<topic>/time_s`` (N,), ``xi`` and ``xidot`` (N, n_m) for each state series (``<topic>``
  is ``/cdgps/state`` or ``/cdgps/state_filtered``);
* for the estimate (``/cdgps/state``) its modal-position covariance, ``P_xi_triu``
  (N, n_m(n_m+1)/2: the upper triangle row by row, written when every P_ξ is exactly symmetric)
  or ``P_xi`` (N, n_m, n_m); for the forward filter of a smoothed run only ``sigma_q`` (N, n_q),
  its 1-σ of q;
* with ``--covariance full``: ``P`` (N, n, n), the whole state covariance of both series, and
  P_ξ of the forward filter too;
* ``arrays/cdgps/residuals/``: ``residual_m`` (N, C, float32 — 7 significant digits, nm on
  cm-level residuals; NaN where the channel was not used),
  ``nis`` (N,, NaN where none), ``nis_dof`` (N,), and ``channels.json`` (the C
  ``[antenna, transmitter]`` pairs, the columns of ``residual_m``).

q = ξ Uᵀ and σ_q (the standard deviations of U P_ξ Uᵀ) are computed from these when read.  The
JSON channels hold one message every ``json_channels_every_epochs`` epochs (metadata
``cdgps.estimate``; chosen by ``--foxglove-rate-hz``).
"""

PACKED_PREFIX = "arrays"
RESIDUAL_PACKED = "arrays/cdgps/residuals/"
COVARIANCE_CHOICES = ("modal", "full")
DEFAULT_COVARIANCE = "modal"
DEFAULT_PREVIEW_RATE_HZ = 1.0
"""Rate of the Foxglove JSON channels, Hz (0: every epoch)."""
