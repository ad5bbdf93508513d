"""GPS physics: broadcast orbits and frames, troposphere, receiver clocks, geometry."""
