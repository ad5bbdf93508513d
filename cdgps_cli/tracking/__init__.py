"""GPS L1 C/A signal processing below the carrier-phase logs (Alban et al. 2003): spreading codes,
acquisition and tracking loops.  Numerics only: sample arrays in, arrays and records out."""
