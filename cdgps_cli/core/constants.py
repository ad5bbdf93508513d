"""Physical constants used across cdgps (one source of truth)."""

SPEED_OF_LIGHT_M_S = 299_792_458.0
GPS_L1_HZ = 1_575.42e6
GPS_L1_WAVELENGTH_M = SPEED_OF_LIGHT_M_S / GPS_L1_HZ
STANDARD_GRAVITY_M_S2 = 9.80665
#: largest |t − toe| for which a broadcast ephemeris is used, s (±2 h; the nominal fit interval is 4 h)
MAX_EPHEMERIS_AGE_S = 7200.0
#: u-blox RXM-RAWX carrier lock time saturates at this value, ms (read by the ingest and the rtk paths)
LOCK_TIME_CAP_MS = 64500.0
