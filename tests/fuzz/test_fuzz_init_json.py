"""Fuzz: INIT.json as read by ``cdgps estimate`` (file_checks.read_init_json, ekf.load_init_state).

Property: a mutated INIT.json (a value anywhere in the document replaced by any JSON value, a key
removed, or its bytes mutated) makes ``estimate`` exit 0 or exit 2 with a message naming the INIT
file, no traceback, no STATES.mcap left behind; RUN and INIT are never modified.
"""

from __future__ import annotations

import json

from hypothesis import given
from hypothesis import strategies as st

from fuzz_support import byte_mutation, check_command, cli, fuzz_settings, scratch, sha256

JSON_VALUE = st.one_of(
    st.none(), st.booleans(), st.integers(-2**70, 2**70), st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([1e308, -1e308, 1e-308, -1e9, 1e12, 0, -1, "", "x", [], {}, [[]], [True], [1e308]]),
    st.text(max_size=6), st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=4),
)


def _leaves(doc, path=()):
    """Every (path, value) of a JSON document, containers included (depth first)."""
    yield path, doc
    if isinstance(doc, dict):
        for k, v in doc.items():
            yield from _leaves(v, path + (k,))
    elif isinstance(doc, list):
        for i, v in enumerate(doc[:12]):                  # the first elements of long arrays
            yield from _leaves(v, path + (i,))


def _set(doc, path, value, delete=False):
    if not path:
        return value
    node = doc
    for k in path[:-1]:
        node = node[k]
    if delete and isinstance(node, dict):
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return doc


@st.composite
def json_mutation(draw, text: str):
    doc = json.loads(text)
    paths = [p for p, _ in _leaves(doc) if p]
    path = draw(st.sampled_from(paths))
    delete = draw(st.booleans()) and isinstance(path[-1], str)
    value = draw(JSON_VALUE)
    return f"{'del ' if delete else ''}{'.'.join(map(str, path))} = {value!r}", json.dumps(_set(doc, path, value, delete)).encode()


@fuzz_settings(25)
@given(data=st.data())
def test_estimate_with_a_mutated_init(base, data):
    text = (base / "INIT.json").read_text()
    _, mutated = data.draw(st.one_of(json_mutation(text), json_mutation(text), byte_mutation(text.encode())))
    with scratch() as d:
        f, out = d / "init-mutated.json", d / "STATES.mcap"
        f.write_bytes(mutated)
        run = base / "RUN.mcap"
        before = {f: sha256(f), run: sha256(run)}
        r = cli("estimate", run, "--init", f, "-o", out)
        check_command(r, before, [out], str(f))
