"""The INIT format's kind, for every version cdgps wrote (core/records.py)."""

from cdgps_cli.core.records import INIT_FORMAT, init_kind


def test_init_kind_of_every_version():
    assert init_kind({"format": INIT_FORMAT, "kind": "structure", "state": {}}) == "structure"
    assert init_kind({"format": INIT_FORMAT, "kind": "gnss"}) == "gnss"
    assert init_kind({"format": "cdgps.init/1", "state": {}, "biases": []}) == "structure"   # version 1
    assert init_kind({"kind": "cdgps gnss init", "rovers": {}}) == "gnss"                      # GNSS before version 2
    assert init_kind({"state": {}, "biases": []}) == "structure"                               # hand-made
    for other in ({}, {"kind": "gnss"}, {"format": "cdgps.init/9", "kind": "gnss"}, [], None, "x"):
        assert init_kind(other) is None, other
