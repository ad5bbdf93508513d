"""review7: an INIT integer too large for int64 must be refused (exit 2, the INIT file named, no traceback, no
output), as a non-integer is. FAILS on main 10d72fd: OverflowError traceback (exit 1) from
baseline._given_glonass (np.array(ints, dtype=np.int64)) for a GLONASS dd_integer_cycles; the GPS
integer_cycles case is older than this session (same OverflowError further on)."""

from __future__ import annotations

import json

import pytest

from tests._shared import run_cli
from tests.pipeline.test_gnss_glonass_fix import glonass_fixed  # noqa: F401 (the module's fixture)


@pytest.mark.parametrize("key, system", [("dd_integer_cycles", "R"), ("integer_cycles", "G")])
def test_an_integer_beyond_int64_is_refused(glonass_fixed, tmp_path, key, system):  # noqa: F811
    d, init, _ = glonass_fixed
    bad = json.loads(json.dumps(init))
    entry = next(b for b in bad["biases"] if b["satellite"].startswith(system) and not b["pivot"]
                 and b.get(key) is not None)
    entry[key] = 10 ** 30
    (tmp_path / "bad.json").write_text(json.dumps(bad))
    r = run_cli("-q", "estimate", d / "run.mcap", "--init", tmp_path / "bad.json", "-o", tmp_path / "s.mcap")
    assert r.exit_code == 2 and str(tmp_path / "bad.json") in r.stderr, r.output
    assert "Traceback" not in r.output and not (tmp_path / "s.mcap").exists()
