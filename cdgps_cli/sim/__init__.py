"""Simulators: the structure with its antennas, GNSS receiver pairs (RINEX out)."""
