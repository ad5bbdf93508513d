"""Figures and md/json/html reports, with their provenance."""
