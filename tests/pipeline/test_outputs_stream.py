"""``export`` and ``evaluate`` read STATES a chunk of epochs at a time (issue 29) and give what the
whole-record versions gave (``tests/pipeline/_outputs_reference.py``, the code before): the same CSV
bytes (with and without ``--points``) and the same evaluation, in chunks of 1024 epochs on a record
of 3 chunks, and in one chunk."""

from __future__ import annotations

import json

import pytest

import cdgps_cli.config.options as options
import cdgps_cli.pipeline.estimate_outputs as outputs
from tests._shared import REPO_ROOT, run_cli
from tests.pipeline import _outputs_reference as ref

CFG = REPO_ROOT / "configs" / "testbed-1998.toml"


@pytest.fixture(scope="module")
def record(tmp_path_factory):
    d = tmp_path_factory.mktemp("outputs")
    for args in (("simulate", CFG, "--duration", "215", "--seed", "3", "-o", d / "sim"),
                 ("ingest", d / "sim" / "receiver.csv", "--config", CFG, "-o", d / "run.mcap"),
                 ("init", d / "run.mcap", "--start", "0", "--duration", "20", "-o", d / "init.json"),
                 ("estimate", d / "run.mcap", "--init", d / "init.json", "--smooth", "-o", d / "states.mcap")):
        r = run_cli("-q", *args)
        assert r.exit_code == 0, r.output
    return d


@pytest.mark.parametrize("chunk", [1024, 16384])
def test_export_and_evaluate_as_the_whole_record(record, tmp_path, monkeypatch, chunk):
    monkeypatch.setattr(options, "STATES_CHUNK_EPOCHS", chunk)
    monkeypatch.setattr(outputs, "_EVAL_CHUNK", chunk)
    st = record / "states.mcap"
    for points in (None, "antennas"):
        new = outputs.export_csv(st, tmp_path / "new.csv", points)
        old = ref.export_csv(st, tmp_path / "old.csv", points)
        assert (tmp_path / "new.csv").read_bytes() == (tmp_path / "old.csv").read_bytes()
        assert {**new, "output": ""} == {**old, "output": ""} and new["rows"] > 2 * 1024
    for converge_s in (1.0, 30.0):
        a = outputs.evaluate(record / "sim", st, converge_s)
        b = ref.evaluate(record / "sim", st, converge_s)
        assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)
