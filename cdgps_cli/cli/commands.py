"""Command-line interface: thin click shells over the library functions.

User errors (:class:`CdgpsError`) are printed on stderr as ``cdgps: error: …`` without a traceback
and exit with status 2.  ``--json`` prints a machine-readable summary on stdout; human messages and
progress go to stderr and are silenced by ``--quiet``.
"""

from __future__ import annotations

import sys

# the group and its shared helpers; importing each family module registers its commands on it
from cdgps_cli.cli.app import BROKEN_PIPE_EXIT, _GC_THRESHOLDS, _Group, main  # noqa: F401
from cdgps_cli.cli import stage_commands, gnss_commands, control_commands, tracking_commands, batch_commands  # noqa: F401,E501

if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
