"""A simulator's truth folder as ``cdgps simulate`` writes it: ``truth.json`` (the run's settings,
``config``/``config_sha256``, segments, biases …) and ``truth.csv`` (``time_s`` and a column per
coordinate, ``<name>_<unit>`` or a bare ``<name>`` in files before issue 32).

The one reader of that pair: ``cdgps evaluate``, ``cdgps report run --truth``, ``cdgps report
control`` and the IF-sample simulator read through :func:`read_truth_folder`, and those that compare
with a config's coordinates through :func:`truth_coordinates` and :func:`check_truth_config`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.coordinate_columns import coordinate_table
from cdgps_cli.io.file_checks import refuse_deep_json

#: the truth table and its compressed forms, in the order they are looked for
TRUTH_CSV_NAMES = ("truth.csv", "truth.csv.xz", "truth.csv.gz")


@dataclass(frozen=True)
class SimulationTruth:
    """What :func:`read_truth_folder` read.

    Attributes
    ----------
    folder : Path
    info : dict
        truth.json.
    table : pandas.DataFrame
        truth.csv as written (columns as in the file).
    csv_path : Path
        The truth table read (truth.csv, or its .xz / .gz form).
    """

    folder: Path
    info: dict
    table: object
    csv_path: Path

    @property
    def json_path(self) -> Path:
        return self.folder / "truth.json"


def read_truth_folder(folder: str | Path, option: str | None = None) -> SimulationTruth:
    """truth.json and truth.csv of a ``cdgps simulate`` folder.

    Parameters
    ----------
    folder : path
    option : str, optional
        The command-line option that named the folder (``--truth``), for the messages.

    Raises
    ------
    CdgpsError
        Naming the option and folder if a file is missing or unreadable, or truth.json is not an object.
    """
    import pandas as pd  # noqa: PLC0415 (not on the path of commands that read no truth)

    d = Path(folder)
    csv = next((d / n for n in TRUTH_CSV_NAMES if (d / n).exists()), d / TRUTH_CSV_NAMES[0])
    try:
        text = (d / "truth.json").read_text(encoding="utf-8")
        refuse_deep_json(text, d / "truth.json", "the truth.json of a `cdgps simulate` folder")
        info = json.loads(text)
        table = pd.read_csv(csv)
    except (OSError, ValueError) as exc:
        where = f"{option} {d}" if option else str(d)
        raise CdgpsError(f"{where}: not a `cdgps simulate` folder: cannot read truth.csv / truth.json ({exc})") from None
    if not isinstance(info, dict):
        raise CdgpsError(f"{d / 'truth.json'}: expected a JSON object (a `cdgps simulate` truth), got {type(info).__name__}")
    return SimulationTruth(d, info, table, csv)


def check_truth_config(truth: SimulationTruth, config_sha256: str, config_name: str, estimate: str | Path,
                       option: str = "--truth") -> None:
    """Refuse a truth simulated with another config than the estimate's (truth.json ``config_sha256``;
    a truth without one is accepted); checked before the columns, as it explains missing ones."""
    sha = truth.info.get("config_sha256")
    if sha and sha != config_sha256:
        raise CdgpsError(f"{option} {truth.folder}: simulated with config {truth.info.get('config')!r} (sha256 "
                         f"{str(sha)[:12]}…), but {estimate} estimates config {config_name!r} "
                         f"(sha256 {str(config_sha256)[:12]}…); give the truth of the run that was estimated")


def require_columns(table, names, path: str | Path) -> None:
    """CdgpsError naming ``path`` and every column of ``names`` that ``table`` lacks."""
    missing = [n for n in names if n not in table.columns]
    if missing:
        raise CdgpsError(f"{path}: missing column(s) {', '.join(missing)}")


def truth_coordinates(truth: SimulationTruth, model, names=None):
    """truth.csv with ``time_s`` and a column per coordinate of ``names`` (default: all of ``model``)
    under its bare name (:func:`~cdgps_cli.io.coordinate_columns.coordinate_table`); CdgpsError
    naming the file and the missing column(s)."""
    table, missing = coordinate_table(truth.table, model, names)
    missing = [n for n in ["time_s"] if n not in table.columns] + missing
    if missing:
        raise CdgpsError(f"{truth.csv_path}: missing column(s) {', '.join(missing)}")
    return table
