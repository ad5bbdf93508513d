"""Build of the optional C kernels ``cdgps_cli.estimation._ekfcore``, ``cdgps_cli.estimation._lambdacore`` (LAMBDA's
reduction and integer search), ``cdgps_cli.tracking._trackcore`` and ``cdgps_cli.io._ubxcore`` (the framing walk
of u-blox logs and the RXM-RAWX measurement rows; without it ``cdgps_cli.io.ubx_frames`` and the RAWX decoder use
numpy, same result) (project metadata lives in
pyproject.toml).

The extension is plain C against the CPython API and the buffer protocol: no numpy headers, so
``pip install -e .`` needs only a C compiler and the Python headers.  It is ``optional``: where it
cannot be compiled the install still succeeds and cdgps_cli.estimation.filter uses its pure-numpy path (slower,
same results).  -O3 without -march=native, so a wheel or build runs on any machine of its
architecture.
"""

import sys

from setuptools import Extension, setup

if sys.platform == "win32":
    compile_args = ["/O2"]
else:
    compile_args = ["-O3", "-std=c99"]
# the LAMBDA kernels must round every product and sum as the Python loops do (bit-identical integers):
# no fused multiply-add contraction (gcc's default -ffp-contract=fast would fuse where the target has FMA)
lambda_args = compile_args if sys.platform == "win32" else [*compile_args, "-ffp-contract=off"]
# the filter kernel: sqrt without errno (the same correctly rounded values, but inlined: no libm call per
# square root, loops free to vectorize); ~6 % of `estimate()` on the testbed hour, STATES byte-identical
ekf_args = compile_args if sys.platform == "win32" else [*compile_args, "-fno-math-errno"]
# the orbit kernel must give the numpy functions' values bit for bit: no fused multiply-add, sqrt inlined
orbit_args = compile_args if sys.platform == "win32" else [*compile_args, "-ffp-contract=off", "-fno-math-errno"]

setup(
    ext_modules=[
        Extension(
            "cdgps_cli.estimation._ekfcore",
            sources=["cdgps_cli/estimation/_ekfcore.c"],
            extra_compile_args=ekf_args,
            optional=True,
        ),
        Extension(
            "cdgps_cli.estimation._lambdacore",
            sources=["cdgps_cli/estimation/_lambdacore.c"],
            extra_compile_args=lambda_args,
            optional=True,
        ),
        Extension(
            "cdgps_cli.tracking._trackcore",
            sources=["cdgps_cli/tracking/_trackcore.c"],
            extra_compile_args=compile_args,
            optional=True,
        ),
        Extension(
            "cdgps_cli.model.gps._orbitcore",
            sources=["cdgps_cli/model/gps/_orbitcore.c"],
            extra_compile_args=orbit_args,
            optional=True,
        ),
        Extension(
            "cdgps_cli.io._ubxcore",
            sources=["cdgps_cli/io/_ubxcore.c"],
            extra_compile_args=compile_args,
            optional=True,
        ),
    ]
)
