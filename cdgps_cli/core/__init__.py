"""Foundations every layer may use: errors, physical constants, time scales, progress."""
