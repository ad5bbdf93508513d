"""What STATES.mcap holds and the options that choose it (no numerics: the CLI reads the defaults).

One layout for every kind of estimate (:class:`cdgps_cli.core.records.StateSeries`): a structure's
modal state x = [ξ, ξ̇, …] with q = U ξ, or GNSS displacement states x = ξ = q (C = I, no rates).
``states.json`` describes it: ``format``, ``kind``, ``coord_names``, ``coord_units``, ``n_pos``
(the positions ξ), ``n_rate`` (0 or n_pos), ``wavelength_m`` and per series ``smoothed``,
``messages`` and its ``extra`` arrays; ``arrays/output_map`` is C (n_q, n_pos).

Beside its Foxglove JSON channels (:mod:`cdgps_cli.io.states`), a STATES.mcap carries every epoch
of every series as packed arrays (:mod:`cdgps_cli.io.packed_arrays`), the arrays cdgps itself
reads:

* ``arrays<topic>/time_s`` (N,), ``xi`` (N, n_pos) and, with rates and ``--covariance full``,
  ``xidot`` (N, n_pos) for each state series (no cdgps command reads ξ̇: by default it is in the
  Foxglove channel only, at its rate) (``<topic>`` is ``/cdgps/state``, ``/cdgps/state_filtered`` or, on a GNSS run,
  ``/cdgps/kinematic`` — the single-epoch solutions, with ``extra`` arrays ``n_sat`` and ``pdop``);
* for every series but the forward filter of a smoothed run, its position covariance,
  ``P_xi_triu`` (N, n_pos(n_pos+1)/2: the upper triangle row by row, written when every P_ξ is
  exactly symmetric) or ``P_xi`` (N, n_pos, n_pos); for the forward filter of a smoothed run only
  ``sigma_q`` (N, n_q), its 1-σ of q;
* with ``--covariance full``: ``P`` (N, n, n), the whole state covariance of every series that
  has it, P_ξ of the forward filter too, and ``xidot``;
* the state and covariance arrays (``xi``, ``xidot``, ``P_xi_triu``/``P_xi``, ``sigma_q``, ``P``)
  are packed with :data:`STATE_DELTA` (second differences between epochs, lossless);
* ``arrays/cdgps/residuals/``: ``residual_m`` (N, C, float32 — 7 significant digits, nm on
  cm-level residuals; NaN where the channel was not used),
  ``nis`` (N,, NaN where none), ``nis_dof`` (N,), and ``channels.json`` (the C
  ``[antenna, transmitter]`` pairs, the columns of ``residual_m``).

q = ξ Cᵀ and σ_q (the standard deviations of C P_ξ Cᵀ) are computed from these when read.  The
JSON channels hold one message every ``json_channels_every_epochs`` epochs (metadata
``cdgps.estimate``; chosen by ``--foxglove-rate-hz``).
"""

STATES_FORMAT = "cdgps.states/2"
"""Format of the ``states.json`` description (files without it are version 1)."""
STATES_KINDS = ("structure", "displacement")
SERIES_ATTACHMENT = "states.json"
OUTPUT_MAP_PACKED = "arrays/output_map"
PACKED_PREFIX = "arrays"
RESIDUAL_PACKED = "arrays/cdgps/residuals/"
COVARIANCE_CHOICES = ("modal", "full")
DEFAULT_COVARIANCE = "modal"
DEFAULT_PREVIEW_RATE_HZ = 1.0
"""Rate of the Foxglove JSON channels, Hz (0: every epoch); every epoch is in the packed arrays.  The
lowest rate ``cdgps estimate`` chooses from a config's highest mode
(:func:`cdgps_cli.pipeline.estimate_outputs.preview_rate_hz_for`; the motion is low-pass filtered before
decimation, :mod:`cdgps_cli.analysis.preview`), and the rate of :func:`cdgps_cli.io.states.write_states`
when it is given none.  An hour at 10 Hz: STATES.mcap 19.5 MiB for a 20.6 MiB RUN.mcap (docs/benchmarks/io.md)."""
STATE_DELTA = 2
"""Order of the epoch-to-epoch differences the state and covariance arrays are packed with
(:mod:`cdgps_cli.io.packed_arrays`; lossless: P_ξ of an hour at 10 Hz 10.4 → 9.9 MB)."""
