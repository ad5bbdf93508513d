"""Pipeline stages (../shared/design/architecture.md): functions that wire the numerics, the
simulators and the file formats together (:mod:`.if_chain`: simulated IF samples of a structure →
tracking loops → differential carrier phase → the native receiver log)."""
