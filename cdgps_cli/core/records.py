"""Records passed between the stages: data, not files (the readers and writers are in :mod:`cdgps_cli.io`).

* :data:`OBS_COLUMNS`, :data:`NAV_COLUMNS` — the columns of the observation and broadcast-ephemeris
  tables that the RINEX/UBX readers return and the GNSS models take.
* :data:`INIT_FORMAT` and :func:`init_kind` — the one INIT.json format for both kinds of run.
* :class:`Run` — an ingested recording (what :func:`cdgps_cli.io.run.read_run` returns, or
  :func:`memory_run` builds from tables in memory).
* :class:`StateSeries` (with its :class:`Series`) — an estimate of any kind (a structure's modal
  state, GNSS displacement states): what :func:`cdgps_cli.io.states.write_states` writes to
  STATES.mcap.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Sequence

import numpy as np

from cdgps_cli.core.table import Table

if TYPE_CHECKING:                     # a type only: core imports nothing above it at run time
    from cdgps_cli.config.structure import StructureConfig


@dataclass
class Run:
    """An ingested recording.

    Attributes
    ----------
    path : str
        Where it was read from (``"<memory>"`` for :func:`memory_run`).
    cfg : StructureConfig
        The structure config embedded in the file.
    phase : Table
        Long table time_s, receiver, master, antenna, transmitter, phase_cycles (cycles), lock,
        snr_dbhz (NaN where missing); the name columns categorical.
    gyro : Table
        Long table time_s, gyro, rate_rad_s (possibly empty).
    actuators : Table
        Long table time_s, actuator, force_n (possibly empty).
    metadata : dict
        The ``cdgps.ingest`` record.

    A pandas DataFrame given or assigned for a table (None: an empty table) is taken in through
    :meth:`Table.from_frame <cdgps_cli.core.table.Table.from_frame>`; ``run.phase.frame()`` is
    the DataFrame view (a copy: change it, then assign it back).
    """

    path: str
    cfg: StructureConfig
    phase: Table
    gyro: Table
    actuators: Table
    metadata: dict

    def __setattr__(self, name, value):            # a table given as a DataFrame (or None) is taken in
        if name in _TABLE_COLUMNS:
            value = as_table(value, _TABLE_COLUMNS[name])
        object.__setattr__(self, name, value)


_TABLE_COLUMNS = {"phase": ("time_s", "receiver", "master", "antenna", "transmitter", "phase_cycles", "lock", "snr_dbhz"),
                  "gyro": ("time_s", "gyro", "rate_rad_s"), "actuators": ("time_s", "actuator", "force_n")}


def as_table(table, empty_columns: Sequence[str]) -> Table:
    """A :class:`Table` as is; a DataFrame converted; None an empty table of ``empty_columns``."""
    if isinstance(table, Table):
        return table
    if table is None:
        return Table({c: np.array([], dtype=float) for c in empty_columns})
    return Table.from_frame(table)


def memory_run(cfg: StructureConfig, phase, gyro=None, actuators=None, name: str = "<memory>") -> Run:
    """A :class:`Run` from tables already in memory (e.g. ``simulate(...).receiver``), without files:
    what :func:`read_run` returns for the same data.  Missing gyro/actuator tables are empty.

    ``phase``, ``gyro``, ``actuators`` are :class:`Table` s or pandas DataFrames (rows in order;
    the index is ignored)."""
    return Run(name, cfg, phase, gyro, actuators, {})


@dataclass
class Series:
    """One series of states over epochs: the estimate, the forward filter of a smoothed run, the
    single-epoch solutions of a GNSS run.

    Attributes
    ----------
    time_s : ndarray (N,)
        Epoch times, s (run seconds, or GPS seconds on a GNSS run).
    x : ndarray (N, n)
        States (state units; NaN where a state has no solution at that epoch).
    P : ndarray (N, m, m)
        Covariance of the first m ≥ ``n_pos`` states (m = n: the whole state), state units².
    smoothed : bool
        Whether the series is a smoother's output.
    extra : dict of str to ndarray (N, ...)
        Further per-epoch numbers stored beside the states (e.g. ``n_sat``, ``pdop``).
    messages : bool
        Whether the series also gets a Foxglove JSON channel (else its packed arrays only).
    """

    time_s: np.ndarray
    x: np.ndarray
    P: np.ndarray
    smoothed: bool = False
    extra: dict = field(default_factory=dict)
    messages: bool = True


@dataclass
class StateSeries:
    """An estimate of any kind as one record: state series, output map, residuals, NIS, events.

    The states x of every series start with ``n_pos`` positions (the modal positions ξ of a
    structure, or the displacements themselves) followed, when ``n_rate`` > 0, by their rates; the
    reported coordinates are q = C x[:n_pos] with C = ``output_map``.

    Attributes
    ----------
    kind : {"structure", "displacement"}
        A structure's modal state (pseudolite or GNSS run) or GNSS displacement states.
    coord_names : list of str (n_q,)
        Names of the coordinates q.
    coord_units : list of str (n_q,)
        Unit of each coordinate (``"m"``, ``"rad"`` or ``"1"``).
    output_map : ndarray (n_q, n_pos)
        C of q = C x[:n_pos] (the mode shapes U of a structure; the identity for displacements).
    n_rate : int
        Rates stored after the positions (ξ̇: n_pos; 0: none).
    series : dict of str to Series
        By topic; ``/cdgps/state`` (the estimate) always.
    residual_channels : list of (str, str)
        The (antenna or rover, transmitter or satellite) label of each column of ``residual_m``.
    residual_m : ndarray (N, C)
        Post-fit residuals of the estimate, m (NaN where the channel was not used).
    nis, nis_dof : ndarray (N,)
        Normalized innovation squared per epoch (NaN where none) and its degrees of freedom.
    events : list of dict
        ``time_s``, ``antenna``, ``transmitter``, ``kind``, ``action`` and any details.
    wavelength_m : float
        Carrier wavelength the biases are counted in, m.
    """

    kind: str
    coord_names: list
    coord_units: list
    output_map: np.ndarray
    n_rate: int
    series: dict
    residual_channels: list
    residual_m: np.ndarray
    nis: np.ndarray
    nis_dof: np.ndarray
    events: list
    wavelength_m: float

    @property
    def n_pos(self) -> int:
        """Number of position states (columns of ``output_map``)."""
        return int(np.shape(self.output_map)[1])


@dataclass(frozen=True)
class CoordinateModel:
    """The coordinates of a state series that has no structure model (GNSS displacement states):
    what spectra need of a config — name, coordinate names and units — with no modes and no gyros.

    Attributes
    ----------
    name, sha256 : str
        The config the estimate was made with (the GNSS run's).
    coord_names, coord_units : tuple of str (n_q,)
    """

    name: str
    sha256: str
    coord_names: tuple
    coord_units: tuple
    mode_names: tuple = ()
    mode_frequency_hz: tuple = ()
    mode_time_constant_s: tuple = ()
    gyro_names: tuple = ()
    rigid_index: int | None = None

    @property
    def mode_shapes(self) -> np.ndarray:
        """(n_q, 0): no modes."""
        return np.zeros((len(self.coord_names), 0))

    def coord_unit(self, name: str) -> str:
        return self.coord_units[self.coord_names.index(name)]

    def coord_unit_label(self, name: str) -> str:
        return self.coord_unit(name)


OBS_COLUMNS = (
    "time_gps_s",
    "sat",
    "phase_l1_cycles",
    "lli_l1",
    "ssi_l1",
    "pseudorange_l1_m",
    "snr_l1_dbhz",
    "rx_clock_offset_s",
    "epoch_flag",
)
"""Columns of the table returned by :func:`cdgps_cli.io.rinex.read_rinex_obs`."""
NAV_COLUMNS = (
    "sat",
    "toc_gps_s",
    "af0_s",
    "af1_s_per_s",
    "af2_s_per_s2",
    "iode",
    "crs_m",
    "delta_n_rad_per_s",
    "m0_rad",
    "cuc_rad",
    "e",
    "cus_rad",
    "sqrt_a_sqrt_m",
    "toe_sow_s",
    "cic_rad",
    "omega0_rad",
    "cis_rad",
    "i0_rad",
    "crc_m",
    "omega_rad",
    "omega_dot_rad_per_s",
    "idot_rad_per_s",
    "codes_l2",
    "week",
    "l2p_data_flag",
    "sv_accuracy_m",
    "sv_health",
    "tgd_s",
    "iodc",
    "transmit_sow_s",
    "fit_interval_h",
    "toe_gps_s",
    "transmit_gps_s",
    "line",
)
"""Columns of the table returned by :func:`read_rinex_nav`.

The 29 broadcast-orbit values in RINEX order (clock: ``af0_s``, ``af1_s_per_s``,
``af2_s_per_s2``; orbit: ``iode`` … ``idot_rad_per_s``; ``codes_l2``, ``week`` (GPS week of toe,
continuous), ``l2p_data_flag``, ``sv_accuracy_m``, ``sv_health`` (0 = healthy), ``tgd_s``,
``iodc``, ``transmit_sow_s`` (seconds of week of the message), ``fit_interval_h``); derived
``toc_gps_s`` (clock reference time), ``toe_gps_s`` (= week·604800 + toe_sow_s) and
``transmit_gps_s`` in GPS seconds; ``line`` is the first line of the record in the file."""

GLONASS_NAV_COLUMNS = (
    "x_m",
    "y_m",
    "z_m",
    "vx_m_per_s",
    "vy_m_per_s",
    "vz_m_per_s",
    "ax_m_per_s2",
    "ay_m_per_s2",
    "az_m_per_s2",
    "glonass_k",
)
"""Extra columns of the navigation table for GLONASS state-vector records (NaN on other rows):
PZ-90 position, velocity and luni-solar acceleration at t_b (``toe_gps_s`` = ``toc_gps_s``), and the
frequency number k.  On a GLONASS row of :data:`NAV_COLUMNS`, ``af0_s`` = −τ_n, ``af1_s_per_s`` =
γ_n, ``af2_s_per_s2`` = 0, ``sv_health`` = the health flag, ``transmit_sow_s`` = the message frame
time (GPS seconds of week), ``week`` = the GPS week of t_b; the Kepler elements are NaN."""


#: INIT.json format written by ``cdgps init`` (both kinds).  Version 2 adds ``kind`` and gives a GNSS
#: INIT the same ``biases`` list as a structure INIT: one entry per ambiguity segment, each with
#: ``bias_m``, ``sigma_m`` (0 when fixed), ``integer_cycles`` (None when not fixed), ``fixed``,
#: ``segment_start_s``, ``segment_end_s`` and the channel — ``antenna``/``transmitter`` for a
#: structure, ``rover``/``satellite``/``reference`` (and ``master``) for satellite double differences.
#: A GLONASS entry (FDMA: no common wavelength) keeps ``integer_cycles`` None and ``fixed`` false; with
#: ``glonass_fix`` it also carries ``dd_integer_cycles`` (N_i − N_r, each satellite in its own cycles; 0 on the
#: reference), ``fdma_channel`` and ``reference_fdma_channel`` — optional keys, so older INITs stay readable.
INIT_FORMAT = "cdgps.init/2"
#: the GNSS INIT's ``kind`` before version 2 (no ``format``, no ``biases``): still read
LEGACY_GNSS_INIT_KIND = "cdgps gnss init"


def init_kind(init) -> str | None:
    """``"structure"``, ``"gnss"`` or None (not an INIT cdgps wrote) for INIT.json contents, any version."""
    if not isinstance(init, dict):
        return None
    kind = init.get("kind")
    if kind == LEGACY_GNSS_INIT_KIND or (kind == "gnss" and init.get("format") == INIT_FORMAT):
        return "gnss"
    if kind == "structure" or init.get("format") == "cdgps.init/1" or "state" in init:
        return "structure"
    return None

