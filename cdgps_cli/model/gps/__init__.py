"""GPS models: orbits from broadcast ephemerides, troposphere, receiver clocks and epoch alignment, SPP."""
