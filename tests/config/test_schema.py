"""The structure config's keys are declared once (cdgps_cli/config/schema.py): parse_config judges
unknown and missing keys by that table, and the published JSON Schema (docs/schema/) is generated
from it and from the bounds, so editors check a config the way cdgps does (issue 32 item 6)."""

from __future__ import annotations

import importlib.util
import json
import tomllib
from pathlib import Path

import jsonschema
import pytest

from cdgps_cli.config.limits import CONFIG_BOUNDS
from cdgps_cli.config.schema import STRUCTURE_TABLES, optional_keys, required_keys, structure_json_schema
from cdgps_cli.config.structure import _SIM_DEFAULTS, config_kind, parse_config
from cdgps_cli.core.errors import CdgpsError

ROOT = Path(__file__).resolve().parents[2]
SCHEMA = structure_json_schema(_SIM_DEFAULTS)
STRUCTURE_CONFIGS = [p for p in sorted((ROOT / "configs").glob("*.toml")) if config_kind(p.read_text()) == "structure"]


def test_the_published_schema_is_the_generated_one():
    spec = importlib.util.spec_from_file_location("mk", ROOT / "scripts" / "make_config_schema.py")
    mk = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mk)
    assert mk.OUT.read_text() == mk.schema_text(), "run scripts/make_config_schema.py"
    jsonschema.Draft202012Validator.check_schema(json.loads(mk.OUT.read_text()))


@pytest.mark.parametrize("path", STRUCTURE_CONFIGS, ids=lambda p: p.name)
def test_every_shipped_structure_config_validates(path):
    assert len(STRUCTURE_CONFIGS) >= 4
    jsonschema.validate(tomllib.loads(path.read_text()), SCHEMA)


def _node(pattern: str):
    """The schema node of a CONFIG_BOUNDS pattern (``modes[].shape[]``, ``antennas[].displacement_m.*[]`` …)."""
    table, _, rest = pattern.partition(".")
    node = SCHEMA["properties"][table.removesuffix("[]")]
    node = node["items"] if table.endswith("[]") else node
    key, _, tail = rest.partition(".")
    node = node["properties"][key.split("[")[0]]
    if tail == "*[]":
        return node["additionalProperties"]["items"]
    for _ in range(key.count("[]")):
        node = node["items"]
    return node


@pytest.mark.parametrize("pattern", sorted(CONFIG_BOUNDS))
def test_every_bound_is_in_the_schema(pattern):
    b = CONFIG_BOUNDS[pattern]
    node = _node(pattern)
    assert node["maximum"] == b.hi
    assert node["exclusiveMinimum" if b.lo_open else "minimum"] == b.lo


@pytest.mark.parametrize("table", sorted(STRUCTURE_TABLES))
def test_an_unknown_key_and_a_missing_one_are_refused_by_both(table, testbed_text):
    doc = tomllib.loads(testbed_text)
    name = table.removesuffix("[]")
    if name not in doc:
        pytest.skip(f"the testbed config has no [{name}]")
    first = doc[name][0] if table.endswith("[]") else doc[name]
    first["no_such_key"] = 1
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(doc, SCHEMA)
    header = f"[[{name}]]\n" if table.endswith("[]") else f"[{name}]\n"
    with pytest.raises(CdgpsError, match="no_such_key: unknown key"):
        parse_config(testbed_text.replace(header, header + "no_such_key = 1\n", 1))
    assert required_keys(table) | optional_keys(table) == set(STRUCTURE_TABLES[table])


def test_a_missing_required_key_is_refused_by_both(testbed_text):
    doc = tomllib.loads(testbed_text)
    del doc["model"]["sample_period_s"]
    with pytest.raises(jsonschema.ValidationError, match="sample_period_s"):
        jsonschema.validate(doc, SCHEMA)
    lines = [ln for ln in testbed_text.splitlines(keepends=True) if not ln.startswith("sample_period_s")]
    with pytest.raises(CdgpsError, match="model.sample_period_s: missing required key"):
        parse_config("".join(lines))


# ---- the GNSS run config


GNSS_CONFIGS = [p for p in sorted((ROOT / "configs").glob("*.toml")) if config_kind(p.read_text()) == "gnss"]


def test_the_published_gnss_schema_is_the_generated_one():
    spec = importlib.util.spec_from_file_location("mk", ROOT / "scripts" / "make_config_schema.py")
    mk = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mk)
    assert mk.GNSS_OUT.read_text() == mk.gnss_schema_text(), "run scripts/make_config_schema.py"
    jsonschema.Draft202012Validator.check_schema(json.loads(mk.GNSS_OUT.read_text()))


@pytest.mark.parametrize("path", GNSS_CONFIGS, ids=lambda p: p.name)
def test_every_shipped_gnss_config_validates(path):
    from cdgps_cli.config.schema import gnss_json_schema

    assert len(GNSS_CONFIGS) >= 2
    jsonschema.validate(tomllib.loads(path.read_text()), gnss_json_schema())


def test_gnss_unknown_keys_are_refused_by_both():
    from cdgps_cli.config.schema import gnss_json_schema
    from cdgps_cli.config.structure import parse_gnss_config

    text = '[gnss]\nmaster = "A"\nbogus = 1\n[gnss.antennas.A]\nrinex = "a.obs"\nnope = 2\n'
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(tomllib.loads(text), gnss_json_schema())
    with pytest.raises(CdgpsError) as e:
        parse_gnss_config(text)
    assert "gnss.bogus: unknown key" in str(e.value) and "gnss.antennas.A.nope: unknown key" in str(e.value)
