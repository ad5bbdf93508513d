"""cdgps: carrier-phase differential GPS sensing of flexible structures."""

import os as _os

# cdgps works on many small matrices (18–90 wide), where a multi-threaded BLAS only adds
# synchronization cost (measured: 40× slower filter on a loaded 2-core machine).  Default the BLAS
# to one thread unless the user chose otherwise; this must happen before numpy is imported.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")

__version__ = "0.1.0"
