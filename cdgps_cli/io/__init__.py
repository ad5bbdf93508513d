"""File formats at the package's edge (../shared/design/architecture.md): MCAP containers, RUN,
INIT and STATES files.  Being assembled: :mod:`.packed_arrays` holds the compact binary arrays
that RUN.mcap and STATES.mcap carry beside their Foxglove channels."""
