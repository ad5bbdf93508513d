"""Estimation engine (../shared/design/architecture.md): ambiguity resolution, batch solver, the one
forward filter and smoother.  Being assembled: :mod:`.kalman` holds the filter's step functions."""
