"""Checks that an MCAP file opens in viewers: schemas Foxglove decodes, messages valid against them.

Foxglove (and its open-source fork Lichtblick, ``packages/mcap-support/src/parseJsonSchema.ts``)
turns a ``jsonschema`` channel's schema into message definitions for its panels.  Its rules, as
restated here from reading that decoder (no code taken from it):

* the schema, and every nested object schema, has ``"type": "object"``; its ``properties`` (may
  be absent) are the fields;
* a field with ``oneOf`` is accepted only when every alternative has a numeric ``const`` (an
  enumeration); any other ``oneOf`` is refused;
* otherwise the field's ``type`` must be a single string: ``boolean``, ``number``, ``integer``,
  ``string`` (with no ``contentEncoding``, or ``"base64"``), ``object`` (checked recursively) or
  ``array``; a list of types (``["number", "null"]``), ``"null"``, a missing ``type`` or any other
  word is refused;
* an ``array`` field needs an ``items`` schema whose ``type`` is ``boolean``, ``number``,
  ``integer``, ``string`` (no ``contentEncoding`` at all) or ``object`` (recursive); arrays of
  arrays, item type lists and missing items are refused.

A message is decoded with JavaScript's ``JSON.parse``, which refuses ``NaN`` and ``Infinity``.
Panels such as Plot address a field by a message path (``/cdgps/angles_deg.C2_z``) whose names
are letters, digits, ``_`` and ``-`` (:func:`path_name_problems`).

:func:`check_mcap` applies these rules to every channel of a file read with the official ``mcap``
reader after the file's integrity is checked (:func:`cdgps_cli.io.mcap.open_verified`: summary
and data-section CRCs, metadata checksums; failures listed under ``integrity``), validates every
message against its channel's schema with the
``jsonschema`` package (when installed: it is a test dependency), and checks the time fields:
``timestamp`` equal to the log and publish times, which are Unix time for the channel's
``time_scale`` (:mod:`cdgps_cli.core.timescales`).  Usage: ``python -m cdgps_cli.io.mcap_check FILE…``.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

from cdgps_cli.core.timescales import TIME_SCALES, unix_ns

_SCALARS = ("boolean", "number", "integer")


def foxglove_schema_problems(schema, name: str = "") -> list[str]:
    """What Foxglove's JSON-schema decoder would refuse in ``schema`` (empty list: accepted).

    Parameters
    ----------
    schema : dict
        A channel's JSON schema (parsed).
    name : str
        Field path prefix used in the messages.

    Returns
    -------
    list of str
        One line per refused field, naming its path and the reason.
    """
    if not isinstance(schema, dict):
        return [f"{name or '<root>'}: schema is not a JSON object"]
    if schema.get("type") != "object":
        return [f"{name or '<root>'}: expected \"type\": \"object\", got {json.dumps(schema.get('type'))}"]
    props = schema.get("properties", {})
    if not isinstance(props, dict):
        return [f"{name or '<root>'}: properties is not an object"]
    problems = []
    for field, fs in props.items():
        path = f"{name}.{field}" if name else field
        if not isinstance(fs, dict):
            problems.append(f"{path}: field schema is not an object")
        elif "oneOf" in fs and isinstance(fs["oneOf"], list):
            if not all(isinstance(a, dict) and _is_number(a.get("const")) for a in fs["oneOf"]):
                problems.append(f"{path}: oneOf alternatives must all have numeric const values")
        else:
            problems += _field_problems(fs, path)
    return problems


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _field_problems(fs: dict, path: str) -> list[str]:
    t = fs.get("type")
    if t in _SCALARS:
        return []
    if t == "string":
        enc = fs.get("contentEncoding")
        return [] if enc in (None, "base64") else [f"{path}: unsupported contentEncoding {json.dumps(enc)}"]
    if t == "object":
        return foxglove_schema_problems(fs, path)
    if t == "array":
        items = fs.get("items")
        if not isinstance(items, dict):
            return [f"{path}: array without an items schema"]
        it = items.get("type")
        if it in _SCALARS:
            return []
        if it == "string":
            return [] if "contentEncoding" not in items else [f"{path}: contentEncoding on string array items"]
        if it == "object":
            return foxglove_schema_problems(items, path)
        return [f"{path}: unsupported array item type {json.dumps(it)}"]
    return [f"{path}: unsupported type {json.dumps(t)}"]


_PATH_ID = re.compile(r"[A-Za-z0-9_-]+")


def path_name_problems(schema: dict, name: str = "") -> list[str]:
    """Field names a Foxglove message path (``/topic.field.sub``) cannot spell: its identifiers are
    letters, digits, ``_`` and ``-`` only (Plot panels address fields by these paths)."""
    out = []
    for k, fs in (schema.get("properties") or {}).items() if isinstance(schema, dict) else ():
        path = f"{name}.{k}" if name else k
        if not _PATH_ID.fullmatch(k):
            out.append(f"{path}: name cannot be written in a message path (letters, digits, _ and - only)")
        if isinstance(fs, dict) and fs.get("type") == "object":
            out += path_name_problems(fs, path)
        elif isinstance(fs, dict) and fs.get("type") == "array" and isinstance(fs.get("items"), dict):
            out += path_name_problems(fs["items"], path)
    return out


def undeclared_fields(schema: dict, msg, name: str = "") -> list[str]:
    """Message members that the schema does not declare (Foxglove's panels would not list them)."""
    out = []
    if not isinstance(msg, dict) or not isinstance(schema, dict):
        return out
    props = schema.get("properties", {})
    for k, v in msg.items():
        path = f"{name}.{k}" if name else k
        if k not in props:
            out.append(path)
        elif props[k].get("type") == "object":
            out += undeclared_fields(props[k], v, path)
    return out


def _refuse_constant(token: str):
    raise ValueError(f"{token} is not JSON (JSON.parse refuses it)")


def check_mcap(path: str | Path, validate: bool = True, max_problems: int = 20) -> dict:
    """Check every channel and message of an MCAP file (see the module docstring).

    Parameters
    ----------
    path : path
        The MCAP file.
    validate : bool
        Validate messages with ``jsonschema`` (ImportError when it is not installed).
    max_problems : int
        Problems kept per channel (all are counted).

    Returns
    -------
    dict
        ``file``, ``messages``, ``failures`` (messages with any problem plus refused schemas plus
        integrity failures), ``integrity`` (messages of failed CRC / checksum checks) and per
        topic ``channels[topic] = {schema, messages, failures, schema_problems, problems}``.
    """
    from mcap.reader import make_reader  # noqa: PLC0415

    from cdgps_cli.core.errors import CdgpsError  # noqa: PLC0415
    from cdgps_cli.io.mcap import open_verified  # noqa: PLC0415

    try:
        with open_verified(path):                    # summary and data-section CRCs, metadata checksums
            integrity = []
    except CdgpsError as exc:
        integrity = [str(exc)]
    validators = {}
    if validate:
        from jsonschema import validators as jsv  # noqa: PLC0415
    channels: dict[str, dict] = {}
    total = failures = 0
    with open(path, "rb") as fh:
        reader = make_reader(fh, validate_crcs=True)
        summary = reader.get_summary()
        for ch_id, ch in (summary.channels.items() if summary else ()):
            sc = summary.schemas.get(ch.schema_id)
            rec = channels[ch.topic] = {"schema": sc.name if sc else "", "messages": 0, "failures": 0,
                                        "schema_problems": [], "problems": []}
            if ch.message_encoding != "json" or sc is None or sc.encoding != "jsonschema":
                rec["schema_problems"].append(f"message encoding {ch.message_encoding!r} / schema encoding "
                                              f"{sc.encoding if sc else None!r}: expected json / jsonschema")
                continue
            schema = json.loads(sc.data)
            rec["schema_problems"] += foxglove_schema_problems(schema) + path_name_problems(schema)
            scale = ch.metadata.get("time_scale")
            if scale not in TIME_SCALES:
                rec["schema_problems"].append(f"channel metadata time_scale {scale!r}: expected one of {TIME_SCALES}")
            if validate:
                from jsonschema.exceptions import SchemaError  # noqa: PLC0415

                cls = jsv.validator_for(schema)
                try:
                    cls.check_schema(schema)
                    validators[ch_id] = (cls(schema), schema, scale)
                except SchemaError as exc:
                    rec["schema_problems"].append(f"not a valid JSON schema: {exc.message} "
                                                  f"(at {'/'.join(map(str, exc.absolute_path))})")
                    validators[ch_id] = (None, schema, scale)
            else:
                validators[ch_id] = (None, schema, scale)
        for rec in channels.values():
            failures += bool(rec["schema_problems"])
        for _, channel, message in reader.iter_messages():
            rec = channels[channel.topic]
            rec["messages"] += 1
            total += 1
            v, schema, scale = validators.get(channel.id, (None, None, None))
            probs = []
            try:
                msg = json.loads(message.data, parse_constant=_refuse_constant)
            except ValueError as exc:
                probs.append(f"not JSON: {exc}")
                msg = None
            if msg is not None and schema is not None:
                if v is not None:
                    probs += [f"{'/'.join(map(str, e.absolute_path)) or '<root>'}: {e.message}"
                              for e in v.iter_errors(msg)]
                probs += [f"{f}: not declared in the schema" for f in undeclared_fields(schema, msg)]
                probs += _time_problems(msg, message, scale)
            if probs:
                rec["failures"] += 1
                failures += 1
                if len(rec["problems"]) < max_problems:
                    rec["problems"].append(f"message {message.sequence} ({message.log_time} ns): " + "; ".join(probs[:3]))
    return {"file": str(path), "messages": total, "failures": failures + len(integrity), "channels": channels,
            "integrity": integrity}


def _time_problems(msg: dict, message, scale) -> list[str]:
    out = []
    if message.log_time != message.publish_time:
        out.append("log_time != publish_time")
    ts = msg.get("timestamp")
    if isinstance(ts, dict) and isinstance(ts.get("sec"), int) and isinstance(ts.get("nsec"), int):
        if ts["sec"] * 1_000_000_000 + ts["nsec"] != message.log_time:
            out.append("timestamp differs from the log time")
    if isinstance(msg.get("time_s"), (int, float)) and scale in TIME_SCALES:
        if unix_ns(msg["time_s"], scale) != message.log_time:
            out.append(f"log time {message.log_time} is not time_s {msg['time_s']!r} ({scale}) in Unix ns")
    return out


def main(argv=None) -> int:
    """Print a line per channel; exit 1 when anything fails."""
    bad = 0
    for p in (argv if argv is not None else sys.argv[1:]):
        r = check_mcap(p)
        print(f"{p}: {r['messages']} messages, {r['failures']} failures")
        for line in r["integrity"]:
            print(f"  integrity: {line}")
        for topic, c in r["channels"].items():
            print(f"  {topic} ({c['schema']}): {c['messages']} messages, {c['failures']} failures")
            for line in c["schema_problems"] + c["problems"]:
                print(f"    {line}")
        bad += r["failures"]
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
