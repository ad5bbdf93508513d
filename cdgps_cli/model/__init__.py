"""Models of the physics (architecture.md): kinematics, dynamics, and gps/ (orbits, troposphere, clocks, SPP)."""
