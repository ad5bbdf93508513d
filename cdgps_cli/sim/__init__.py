"""Simulators (../shared/design/architecture.md): the structure simulator, the GNSS simulators and
the GPS L1 C/A front-end sample simulator (:mod:`.if_samples`)."""
