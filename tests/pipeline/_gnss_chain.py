"""A GNSS run config through ingest → init → estimate --smooth → evaluate, as the estimate tests run it."""

from __future__ import annotations

import json

from tests._shared import run_cli


def estimate_chain(d, cfg_text: str, tag: str):
    """``cfg_text`` written to ``d/<tag>.toml`` and run through the chain (files ``run_/init_/states_<tag>``): the
    estimate's JSON summary and evaluate's against ``d``'s truth (None when evaluate refuses, e.g. no truth.csv)."""
    cfg = d / f"{tag}.toml"
    cfg.write_text(cfg_text)
    for args in (["ingest", "--config", cfg, "-o", d / f"run_{tag}.mcap"],
                 ["init", d / f"run_{tag}.mcap", "-o", d / f"init_{tag}.json"]):
        r = run_cli("-q", *args)
        assert r.exit_code == 0, r.output
    r = run_cli("-q", "estimate", d / f"run_{tag}.mcap", "--init", d / f"init_{tag}.json", "--smooth",
                "-o", d / f"states_{tag}.mcap", "--json")
    assert r.exit_code == 0, r.output
    est = json.loads(r.stdout)
    r = run_cli("-q", "evaluate", "--truth", d, "--estimate", d / f"states_{tag}.mcap", "--json")
    return est, (json.loads(r.stdout) if r.exit_code == 0 else None)
