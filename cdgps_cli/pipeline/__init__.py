"""Stage functions that tie files, models and estimators together (GNSS paths)."""
