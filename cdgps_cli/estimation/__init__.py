"""Estimation engine (../shared/design/architecture.md): ambiguity resolution, batch solver, the one
forward filter and smoother.  :mod:`.kalman` holds the forward filter's step (``StepFilter``)."""
