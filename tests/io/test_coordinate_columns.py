"""Units in the coordinate columns of exported CSVs (issue 32 item 5; cdgps_cli/io/coordinate_columns.py)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from cdgps_cli.config.structure import load_config
from cdgps_cli.core.records import CoordinateModel
from cdgps_cli.io.coordinate_columns import column_unit, coordinate_columns, coordinate_table, sigma_column

ROOT = Path(__file__).resolve().parents[2]


def test_the_unit_comes_from_the_kind_and_a_modal_coordinates_label():
    testbed = load_config(ROOT / "configs" / "testbed-1998.toml")
    assert coordinate_columns(testbed)[:3] == ["q1_m", "q2_rad", "q3_rad"]
    assert sigma_column("q10", column_unit(testbed, "q10")) == "sigma_q10_rad"
    tower = load_config(ROOT / "configs" / "tower-120m-fe.toml")          # unit = "m at the top (x)"
    assert coordinate_columns(tower)[0] == "qx-1_m"
    mast = load_config(ROOT / "configs" / "fe-mast-noise.toml")           # modal, no unit label
    assert coordinate_columns(mast)[0] == "xi1_1"
    gnss = CoordinateModel("run", "0" * 64, ("0759_e", "0759_n", "0759_u"), ("m", "m", "m"))
    assert coordinate_columns(gnss) == ["0759_e_m", "0759_n_m", "0759_u_m"]


def test_readers_take_the_suffixed_column_and_accept_a_bare_one():
    model = CoordinateModel("run", "0" * 64, ("a", "b", "c"), ("m", "rad", "m"))
    df = pd.DataFrame({"time_s": [0.0, 1.0], "a_m": [1.0, 2.0], "a": [9.0, 9.0], "b": [3.0, 4.0]})
    table, missing = coordinate_table(df, model)
    assert list(table.columns) == ["time_s", "a", "b"] and missing == ["c_m"]
    assert table["a"].tolist() == [1.0, 2.0] and table["b"].tolist() == [3.0, 4.0]      # a_m preferred over a
