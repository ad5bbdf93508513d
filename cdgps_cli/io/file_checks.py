"""What kind of cdgps file a path holds, and whether an INIT.json belongs to a RUN.mcap.

Every command that reads a cdgps MCAP says which kinds it takes; :func:`require_kind` refuses any
other with a message naming the file, what was expected and what it is (a STATES.mcap given as
``--gyro``, a RUN.mcap given to ``export``, …) before anything is written.  The kind is read from
the metadata records that ``ingest`` (``cdgps.ingest``) and ``estimate`` (``cdgps.estimate``) write,
without decoding any message, after the file's CRCs and the records' own checksums are verified
(:mod:`cdgps_cli.io.mcap_integrity`).

:func:`check_init_run` compares INIT.json's ``run_sha256`` (the RUN it was made from) with the
RUN being estimated: an INIT from another run fits biases of the wrong run, which shows only as
outlier events later.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

from cdgps_cli.io.atomic import file_sha256
from cdgps_cli.core.errors import CdgpsError

STRUCTURE_RUN = "structure RUN.mcap (from 'cdgps ingest' of receiver/gyro CSV logs)"
GNSS_RUN = "GNSS RUN.mcap (from 'cdgps ingest --rinex/--ubx')"
STRUCTURE_STATES = "structure STATES.mcap (from 'cdgps estimate')"
GNSS_STATES = "GNSS STATES.mcap (from 'cdgps estimate' of a GNSS run)"
RUNS = (STRUCTURE_RUN, GNSS_RUN)
STATES = (STRUCTURE_STATES, GNSS_STATES)

NOT_MCAP = "not a valid MCAP file (it does not start with the MCAP magic bytes)"
_MAGIC = b"\x89MCAP0\r\n"
_INGEST, _ESTIMATE, _TRACK = "cdgps.ingest", "cdgps.estimate", "track"


def mcap_kind(path: str | Path) -> str:
    """One of the kinds above, or a description of what else the file is.

    The metadata is read through :func:`cdgps_cli.io.mcap_integrity.read_metadata`, after the file's
    CRCs are checked: a damaged MCAP is a CdgpsError naming the file and the failing region, as is
    a file that cannot be opened."""
    from cdgps_cli.io.mcap_integrity import read_metadata  # noqa: PLC0415

    if not Path(path).is_file():
        raise CdgpsError(f"{path}: no such file")
    try:
        with open(path, "rb") as fh:
            if fh.read(len(_MAGIC)) != _MAGIC:
                return NOT_MCAP
    except OSError as exc:
        raise CdgpsError(f"{path}: cannot read: {exc.strerror}") from None
    meta = read_metadata(path)
    if _ESTIMATE in meta:
        return GNSS_STATES if meta[_ESTIMATE].get("kind") == "gnss" else STRUCTURE_STATES
    if _INGEST in meta:
        return GNSS_RUN if meta[_INGEST].get("kind") == "gnss" else STRUCTURE_RUN
    if _TRACK in meta:
        return "TRACK.mcap of receiver tracking loops (from 'cdgps track'; its phases are not a RUN's observations)"
    return "an MCAP file without cdgps metadata (not written by 'cdgps ingest' or 'cdgps estimate')"


def require_kind(path: str | Path, expected: tuple[str, ...] | str, role: str) -> str:
    """Refuse ``path`` unless it is of one of the ``expected`` kinds.

    ``role`` names the argument in the message (e.g. ``"--gyro"``, ``"STATES_MCAP"``).  Returns the
    kind; a damaged MCAP is a CdgpsError (:func:`mcap_kind`)."""
    expected = (expected,) if isinstance(expected, str) else tuple(expected)
    kind = mcap_kind(path)
    if kind in expected:
        return kind
    want = " or ".join(f"a {e}" for e in expected)
    got = kind if kind.startswith(("not ", "an ")) else f"a {kind}"
    raise CdgpsError(f"{role} {path}: expected {want}; this file is {got}")


def check_init_run(init: dict, init_path: str | Path, run_path: str | Path, allow_other_run: bool = False) -> dict:
    """Does INIT.json come from this RUN?  INIT records the sha256 of its run (``run_sha256``).

    Returns ``{"run_sha256", "init_run_sha256", "matches", "allowed"}`` (``matches`` None when INIT
    records no run, e.g. a hand-made INIT).  Raises CdgpsError on a mismatch unless
    ``allow_other_run``."""
    run_sha = file_sha256(run_path)
    rec = init.get("run_sha256") if isinstance(init, dict) else None
    if rec is not None and not isinstance(rec, str):
        raise CdgpsError(f"{init_path}: run_sha256: expected a hex string, got {rec!r}")
    matches = None if rec is None else (rec.lower() == run_sha)
    if matches is False and not allow_other_run:
        raise CdgpsError(f"{init_path} was made from another run than {run_path}: INIT records run_sha256 "
                         f"{rec[:12]}…, {run_path} has {run_sha[:12]}…; give the INIT.json that 'cdgps init' made "
                         f"from {run_path} (or --allow-other-run to use this one anyway)")
    return {"run_sha256": run_sha, "init_run_sha256": rec, "matches": matches,
            "allowed": bool(matches is False and allow_other_run)}


#: deepest nesting of arrays/objects accepted in INIT.json (cdgps writes at most 3: P's rows)
MAX_JSON_DEPTH = 64


def read_init_json(path: str | Path) -> tuple[dict, str]:
    """(INIT.json as a dict, its text), or a CdgpsError naming the file and the line.

    Refuses an unreadable file, bytes that are not UTF-8, invalid JSON, nesting deeper than
    :data:`MAX_JSON_DEPTH` (checked before parsing: no recursion limit is reached) and a document
    that is not an object."""
    try:
        raw = Path(path).read_bytes()
    except OSError as exc:
        raise CdgpsError(f"{path}: cannot read: {exc.strerror}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        raise CdgpsError(f"{path}, line {line}: not UTF-8 text (byte {raw[exc.start]:#04x} at offset {exc.start}); "
                         f"expected the INIT.json written by 'cdgps init'") from None
    refuse_deep_json(text, path, "the INIT.json written by 'cdgps init'")
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise CdgpsError(f"{path}, line {exc.lineno}: not valid JSON: {exc.msg}") from None
    if not isinstance(doc, dict):
        raise CdgpsError(f"{path}: expected a JSON object from 'cdgps init'")
    return doc, text


def refuse_deep_json(text: str, path: str | Path, expected: str) -> None:
    """CdgpsError naming ``path`` and the line where the JSON ``text`` nests deeper than
    :data:`MAX_JSON_DEPTH`, before it is parsed (:func:`json.loads` would end in a RecursionError, a
    traceback); ``expected`` says what the file should be ("the INIT.json written by 'cdgps init'")."""
    depth = _json_depth_exceeded(text)
    if depth is not None:
        raise CdgpsError(f"{path}, line {text.count(chr(10), 0, depth) + 1}: JSON nested deeper than "
                         f"{MAX_JSON_DEPTH} levels; expected {expected}")


def _json_depth_exceeded(text: str) -> int | None:
    """Offset where the bracket nesting first exceeds :data:`MAX_JSON_DEPTH` (strings skipped), or None.
    Linear: one pass over the openers, closers and quotes."""
    depth, in_str = 0, False
    for m in _JSON_TOKENS.finditer(text):
        tok = m.group()
        if in_str:
            if tok == '"':
                in_str = False
        elif tok == '"':
            in_str = True
        elif tok in "[{":
            depth += 1
            if depth > MAX_JSON_DEPTH:
                return m.start()
        elif tok in "]}":
            depth -= 1
    return None


_JSON_TOKENS = re.compile(r'\\.|["\[\]{}]')
