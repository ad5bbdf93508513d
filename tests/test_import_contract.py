"""The import contract of cdgps_cli (.importlinter), enforcing.

The target layout (../shared/design/architecture.md) makes imports point one way: numerics never
touch files, io never imports numerics, only the CLI imports click.  The modules live in their
subpackages (issue 13, docs/architecture-map.md) and .importlinter states the rules on them.  This
test runs import-linter through its Python API and asserts every contract, printing the import
chains of a broken one.  (The last report-only contract, numerics-never-touch-files, became
enforcing when the baseline's job-file and RINEX loading moved to pipeline/baseline_job.py.)
"""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("importlinter", reason="import-linter is in the test extra: pip install -e '.[test]'")

import importlinter.api  # noqa: E402,F401  (configures import-linter's adapters)
from importlinter.application.use_cases import create_report, read_user_options  # noqa: E402

CONFIG = Path(__file__).resolve().parents[1] / ".importlinter"

# every contract of .importlinter, asserted
CONTRACTS = ("library-never-imports-cli", "only-cli-imports-click", "numerics-never-render",
             "readers-never-import-estimation", "core-numerics-are-pure", "config-below-numerics", "target-layers",
             "control-is-numerics", "io-never-imports-numerics", "numerics-never-touch-files")


@pytest.fixture(scope="module")
def checks() -> dict:
    """Contract id → (contract, check) from one import-linter run over the installed package."""
    options = read_user_options(str(CONFIG))
    report = create_report(options, cache_dir=None)
    assert not report.could_not_run and not report.invalid_contract_options, report.invalid_contract_options
    by_name = {c.name: (c, chk) for c, chk in report.get_contracts_and_checks()}
    return {o["id"]: by_name[o["name"]] for o in options.contracts_options}


def _broken_text(check) -> str:
    """The import chains that break a contract, one line per chain (importer → imported (line))."""
    lines = []
    for inv in check.metadata.get("invalid_chains", []):
        for chain in inv["chains"]:
            hops = " → ".join([chain[0]["importer"]] + [f"{h['imported']} (l.{h['line_numbers'][0]})" for h in chain])
            lines.append(f"  {inv['downstream_module']} must not import {inv['upstream_module']}: {hops}")
    return "\n".join(lines) or f"  {check.metadata}"


def test_every_contract_is_listed(checks):
    assert sorted(checks) == sorted(CONTRACTS)


@pytest.mark.parametrize("cid", CONTRACTS)
def test_contract_holds(checks, cid):
    contract, check = checks[cid]
    assert check.kept, f"{contract.name} is broken:\n{_broken_text(check)}"
