"""Measurement models: phase models, noise, single/double differencing, multipath."""
