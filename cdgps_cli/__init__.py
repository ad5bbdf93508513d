"""cdgps: carrier-phase differential GPS sensing of flexible structures."""

__version__ = "0.1.0"
