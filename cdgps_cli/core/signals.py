"""GNSS signals: one table of (system, frequency slot) → carrier frequency and RINEX 3 observation codes.

Each signal has a name ``"<system letter>:<slot>"`` (``G:L1``, ``E:E5a`` …), its carrier frequency
(Hz) and wavelength (m, c / f), and the RINEX 3 phase-type attributes tried in order of preference
(the code type of the same attribute gives its pseudorange).  RINEX 2 files carry GPS and GLONASS
``L1``/``L2`` (code ``C1``/``P1``, ``P2``/``C2``: the first the record fills), GPS ``L5`` and, in RINEX 2.11,
Galileo ``L1``/``L5``/``L7`` (E1, E5a, E5b; codes ``C1``, ``C5``, ``C7``).  GLONASS is FDMA: its carrier depends on the satellite's
frequency number k (``GLONASS SLOT / FRQ #``), f = f0 + k Δf, so its wavelength is per satellite.

QZSS (``J``) broadcasts on the GPS carriers (L1 C/A, L2C, L5; IS-QZSS-PNT) and is its own signal group.

Sources: IS-GPS-200/705, IS-QZSS-PNT, Galileo OS SIS ICD, BeiDou ICD B1I/B2a, GLONASS ICD; RINEX 3.04 Table 4-7.
"""

from __future__ import annotations

from dataclasses import dataclass

from cdgps_cli.core.constants import SPEED_OF_LIGHT_M_S

__all__ = ["Signal", "SIGNALS", "SYSTEM_NAMES", "AUTO_SYSTEMS", "OTHER_SYSTEM_NAMES", "common_attributes", "signal", "wavelength_m", "glonass_frequency_hz", "anchor_signal"]


@dataclass(frozen=True)
class Signal:
    """One frequency slot of one constellation."""

    name: str
    """``"G:L1"`` …"""
    system: str
    """RINEX system letter."""
    band: str
    """RINEX 3 band digit of the observation codes."""
    attributes: str
    """RINEX 3 tracking-mode attributes, most preferred first."""
    frequency_hz: float
    """Carrier frequency, Hz (GLONASS: f0 at k = 0)."""
    rinex2: tuple = ()
    """RINEX 2 (phase, code candidates…) types (GPS, GLONASS; GPS L5 and Galileo of RINEX 2.11); a record's
    pseudorange is the first candidate it fills."""
    fdma_step_hz: float = 0.0
    """GLONASS channel spacing Δf, Hz (0 for CDMA)."""
    families: tuple = ()
    """The ``attributes`` grouped by the signal they track on this carrier (GPS L2: L2C ``SLX``, P(Y) ``WPYD``…):
    receivers tracking one family see the same satellite biases, two families do not; () — one family."""

    def family(self, attribute: str) -> str:
        """The attributes of the family ``attribute`` belongs to (all of them when the carrier has one)."""
        return next((f for f in self.families if attribute in f), self.attributes)

    @property
    def wavelength_m(self) -> float:
        """c / f, m (GLONASS: at k = 0)."""
        return SPEED_OF_LIGHT_M_S / self.frequency_hz


_F0 = 10.23e6
SIGNALS = {s.name: s for s in (
    Signal("G:L1", "G", "1", "CSLXPWYMN", 154 * _F0, ("L1", "C1", "P1"), families=("C", "SLX", "PWYN", "M")),
    Signal("G:L2", "G", "2", "XLSCWPYDMN", 120 * _F0, ("L2", "P2", "C2"), families=("XLS", "C", "WPYDN", "M")),
    Signal("G:L5", "G", "5", "QIX", 115 * _F0, ("L5", "C5")),
    Signal("E:E1", "E", "1", "CBX", 154 * _F0, ("L1", "C1")),
    Signal("E:E5a", "E", "5", "QIX", 115 * _F0, ("L5", "C5")),
    Signal("E:E5b", "E", "7", "QIX", 118 * _F0, ("L7", "C7")),
    Signal("C:B1I", "C", "2", "IQX", 152.6 * _F0),
    Signal("C:B2I", "C", "7", "IQX", 118 * _F0),
    Signal("C:B2a", "C", "5", "PDX", 115 * _F0),
    Signal("J:L1", "J", "1", "CSLXZ", 154 * _F0, families=("C", "SLX", "Z")),
    Signal("J:L2", "J", "2", "LSX", 120 * _F0),
    Signal("J:L5", "J", "5", "QIX", 115 * _F0),
    Signal("R:G1", "R", "1", "CP", 1602.0e6, ("L1", "C1", "P1"), 0.5625e6, families=("C", "P")),
    Signal("R:G2", "R", "2", "CP", 1246.0e6, ("L2", "P2", "C2"), 0.4375e6, families=("C", "P")),
)}
"""Every supported signal by name."""

SYSTEM_NAMES = {"G": "GPS", "E": "Galileo", "C": "BeiDou", "J": "QZSS", "R": "GLONASS"}

#: the RINEX systems no signal of :data:`SIGNALS` belongs to, by name (named when a file holds their phases)
OTHER_SYSTEM_NAMES = {"S": "SBAS", "I": "NavIC/IRNSS"}

AUTO_SYSTEMS = ("G", "E", "C", "R")
"""Systems whose signals ``--signals auto`` (``rtk``, ``config``) takes when every receiver holds them.  QZSS is
processed in every path when its signals are named (``J:L1``, ``J:L2``, ``J:L5``: a reference satellite of its
own per signal), but ``auto`` leaves it out, and says so: on the real car pair of ../shared/data (a GEONET base
5.3 km away, 4 QZSS satellites in view) every signal with QZSS fixed 144 of 360 epochs instead of 359 — its J03,
at 15–16° behind the car's obstructions, slipped unflagged 20 times in 6 min on L5 and 15 on L2 — while on the
two static real pairs that hold QZSS it changed no fix (docs/gnss-pipeline.md, "QZSS")."""


def common_attributes(name: str, held: dict) -> tuple[dict, bool]:
    """The tracking attribute each receiver's phase of signal ``name`` is read with, one family for all of them.

    ``held``: receiver → the attributes of ``name`` its observation types list (None: not known, a RINEX 2 file,
    taken as holding any; "": none, left to the reader, which refuses it).  The first family (in the order of ``attributes``) every
    receiver holds is chosen, each receiver taking its own first attribute of it: a base holding L2C and P(Y) against
    a rover holding P(Y) alone reads P(Y) too, so each satellite's L2C/P(Y) bias — which does not cancel between two
    receivers tracking different signals — is not in its double differences.  GPS L2 takes L2C first where every
    receiver has it (RTKLIB's code priorities take P(Y) first, which every satellite transmits and L2C only the newer
    ones; P(Y) first fixed fewer of the real car's epochs, 351 against 359 of 360: docs/gnss-pipeline.md). Returns ({receiver: attribute or None}, whether one family serves them all); with none common each
    receiver takes its own first attribute, as before."""
    sig = signal(name)
    known = {rx: a for rx, a in held.items() if a}             # (a receiver without the signal: its reader says so)
    fams = sorted(sig.families or (sig.attributes,), key=lambda f: min(sig.attributes.index(c) for c in f))
    for fam in fams:
        picks = {rx: next((c for c in sig.attributes if c in fam and c in a), None) for rx, a in known.items()}
        if all(v is not None for v in picks.values()):
            return {rx: picks.get(rx) for rx in held}, True
    return {rx: (None if a is None else next((c for c in sig.attributes if c in a), None)) for rx, a in held.items()}, False


def signal(name: str) -> Signal:
    """The :class:`Signal` called ``name``; ValueError listing the known names otherwise."""
    try:
        return SIGNALS[name]
    except KeyError:
        raise ValueError(f"unknown signal {name!r}; known: {', '.join(SIGNALS)}") from None


def glonass_frequency_hz(sig: Signal, k: int) -> float:
    """Carrier of GLONASS frequency number k (−7 … 6) on ``sig``, Hz."""
    if not -7 <= int(k) <= 6:
        raise ValueError(f"GLONASS frequency number must be in −7…6, got {k}")
    return sig.frequency_hz + int(k) * sig.fdma_step_hz


def wavelength_m(name: str, k: int | None = None) -> float:
    """Wavelength of signal ``name`` (GLONASS: of frequency number ``k``, required), m."""
    sig = signal(name)
    if sig.fdma_step_hz:
        if k is None:
            raise ValueError(f"{name} is FDMA: its wavelength needs the satellite's GLONASS frequency number")
        return SPEED_OF_LIGHT_M_S / glonass_frequency_hz(sig, k)
    return sig.wavelength_m


def anchor_signal(signals) -> str | None:
    """The signal whose rows fix each receiver's epochs and clock in the displacement path (``init`` /
    ``estimate``): None — the receiver's GPS L1 table — without ``[gnss] signals`` or when they
    include ``G:L1`` (as always before); otherwise the first signal listed (``E:E1`` for a
    Galileo-only run), so that any single system carries the solution alone."""
    sig = list(signals or ())
    return None if not sig or "G:L1" in sig else str(sig[0])
