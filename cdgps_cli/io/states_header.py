"""The checks every streaming reader of a STATES.mcap makes before reading its arrays.

:class:`cdgps_cli.io.states.StatesChunks` and :class:`cdgps_cli.report.run_data.StatesBlocks` call
:func:`states_spans` on a file opened by :func:`cdgps_cli.io.mcap.open_verified`.
"""

from __future__ import annotations

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.mcap import CONFIG_ATTACHMENT, attachment_spans
from cdgps_cli.io.states_layout import SERIES_ATTACHMENT


def states_spans(path, fh, info, summary) -> tuple[dict, dict]:
    """``(metadata, spans)`` of a STATES.mcap opened by :func:`~cdgps_cli.io.mcap.open_verified`:
    its ``cdgps.estimate`` metadata record and where each attachment is (name → (offset, length)).

    Raises
    ------
    CdgpsError
        Naming ``path``: a RUN.mcap from ``cdgps ingest``, an attachment whose CRC cannot be
        checked, no ``states.json``/config attachment, no ``cdgps.estimate`` metadata.
    """
    from cdgps_cli.io.mcap import _check_attachment_crcs  # noqa: PLC0415 (as read_mcap checks them)
    from cdgps_cli.io.states import ESTIMATE_METADATA  # noqa: PLC0415 (io.states imports this module's users)

    if "cdgps.ingest" in info.metadata:
        raise CdgpsError(f"{path}: this is a RUN.mcap (from 'cdgps ingest'), not a STATES.mcap from 'cdgps estimate'")
    if not info.data_section_crc_checked:
        _check_attachment_crcs(fh, summary, path, zero_ok=False)
    spans = attachment_spans(fh, summary, path)
    if CONFIG_ATTACHMENT not in spans and SERIES_ATTACHMENT not in spans:
        raise CdgpsError(f"{path}: no {SERIES_ATTACHMENT} or config attachment; is this a STATES.mcap from "
                         f"'cdgps estimate'?")
    if ESTIMATE_METADATA not in info.metadata:
        raise CdgpsError(f"{path}: no {ESTIMATE_METADATA!r} metadata record; expected in a STATES.mcap from "
                         f"'cdgps estimate' (damaged or not written by cdgps)")
    return info.metadata[ESTIMATE_METADATA], spans
