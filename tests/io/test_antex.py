"""ANTEX receiver antenna models (io/antex.py): the reader on a file written here, the range correction against its
closed form, and the look-up by type and radome."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cdgps_cli.core.errors import CdgpsError
from cdgps_cli.io.antex import antenna_key, antenna_range_m, find_antenna, read_antex


def _label(text: str, label: str) -> str:
    return f"{text:<60}{label}"


def antenna_block(name: str, freqs: dict, serial: str = "", zen=(0.0, 90.0, 5.0), dazi: float = 5.0) -> list:
    """One ANTEX antenna: ``freqs`` {code: ((north, east, up) mm, NOAZI values mm)}; with azimuth rows (copies of the
    NOAZI row) when ``dazi`` > 0, which the reader passes over."""
    out = [_label("", "START OF ANTENNA"), _label(f"{name:<20}{serial:<20}", "TYPE / SERIAL NO"),
           _label(f"{dazi:8.1f}", "DAZI"), _label(f"{zen[0]:8.1f}{zen[1]:6.1f}{zen[2]:6.1f}", "ZEN1 / ZEN2 / DZEN"),
           _label(f"{len(freqs):6d}", "# OF FREQUENCIES")]
    for code, (neu, var) in freqs.items():
        row = "".join(f"{v:8.2f}" for v in var)
        out += [_label(f"   {code}", "START OF FREQUENCY"), _label("".join(f"{v:10.2f}" for v in neu), "NORTH / EAST / UP"),
                f"   NOAZI{row}"]
        if dazi > 0:
            out += [f"{az:8.1f}{row}" for az in np.arange(0.0, 360.0 + 0.5 * dazi, dazi)]
        out.append(_label(f"   {code}", "END OF FREQUENCY"))
    return out + [_label("", "END OF ANTENNA")]


def write_antex(path, blocks: list) -> None:
    head = [_label("     1.4            M", "ANTEX VERSION / SYST"), _label("A", "PCV TYPE / REFANT"),
            _label("", "END OF HEADER")]
    path.write_text("\n".join(head + [ln for b in blocks for ln in b]) + "\n")


ZEN = np.arange(0.0, 90.1, 5.0)
VAR_L1 = np.round(3.0 * np.sin(np.radians(ZEN) * 2.0), 2)       # mm, 19 values
VAR_L2 = np.round(-2.0 * np.sin(np.radians(ZEN)), 2)


@pytest.fixture
def atx(tmp_path):
    p = tmp_path / "test.atx"
    write_antex(p, [
        antenna_block("BLOCK IIR-M         ", {"G01": ((0, 0, 0), np.zeros(19))}, serial="G05"),   # a satellite's
        antenna_block("LEIAR25.R4      LEIT", {"G01": ((0.6, 0.98, 158.3), VAR_L1), "G02": ((0.3, -0.1, 157.0), VAR_L2)}),
        antenna_block("TRM29659.00     NONE", {"G01": ((-0.06, -0.91, 91.95), VAR_L1)}),
        antenna_block("TRM29659.00     NONE", {"G01": ((9, 9, 9), VAR_L1)}, serial="12345"),    # an individual one
        antenna_block("TRM29659.00     NONE", {"G01": ((1, 1, 1), VAR_L1)}),                     # a type twice: the first
    ])
    return p


def test_the_reader_takes_type_calibrations_and_passes_over_the_rest(atx):
    models = read_antex(atx)
    assert set(models) == {("LEIAR25.R4", "LEIT"), ("TRM29659.00", "NONE")}
    m = models[("LEIAR25.R4", "LEIT")]
    np.testing.assert_array_equal(m.offsets_neu_mm["G01"], [0.6, 0.98, 158.3])
    np.testing.assert_array_equal(m.variations_mm["G02"], VAR_L2)
    np.testing.assert_array_equal(m.zenith_deg, ZEN)
    np.testing.assert_array_equal(models[("TRM29659.00", "NONE")].offsets_neu_mm["G01"], [-0.06, -0.91, 91.95])
    # the signals each frequency serves, with the GPS bands standing in for the other systems'
    assert m.frequency("G:L1") == "G01" and m.frequency("E:E1") == "G01" and m.frequency("C:B2I") == "G02"
    assert m.frequency("G:L5") == "G02" and models[("TRM29659.00", "NONE")].frequency("G:L2") is None


def test_the_range_correction_is_the_offset_along_the_line_of_sight_and_the_variation_at_its_zenith_angle(atx):
    m = read_antex(atx)[("LEIAR25.R4", "LEIT")]
    az = np.radians([0.0, 90.0, 200.0, 33.0, 10.0])
    el = np.radians([90.0, 40.0, 15.0, 62.5, 2.0])
    got = antenna_range_m(m, ["G:L1", "G:L1", "G:L2", "G:L1", "G:L2"], az, el)
    for k in range(az.size):
        f = "G01" if k in (0, 1, 3) else "G02"
        n, e, u = m.offsets_neu_mm[f] * 1e-3
        los = (math.cos(el[k]) * math.sin(az[k]), math.cos(el[k]) * math.cos(az[k]), math.sin(el[k]))
        zen = 90.0 - math.degrees(el[k])
        i = min(int(zen // 5.0), 17)                   # RTKLIB's interpvar: linear between the 5° grid points
        var = (m.variations_mm[f][i] + (zen / 5.0 - i) * (m.variations_mm[f][i + 1] - m.variations_mm[f][i])) * 1e-3
        want = -(e * los[0] + n * los[1] + u * los[2]) + var
        assert got[k] == pytest.approx(want, abs=1e-12), k
    assert got[0] == pytest.approx(-0.1583 + VAR_L1[0] * 1e-3, abs=1e-12)      # at the zenith: the up offset alone
    with pytest.raises(CdgpsError, match=r"test.atx: antenna TRM29659.00 NONE has no calibration for G:L2 \(it has G01\)"):
        antenna_range_m(read_antex(atx)[("TRM29659.00", "NONE")], ["G:L2"], [0.0], [1.0])


def test_an_antenna_is_found_by_type_and_radome_or_by_its_type_without_one(atx):
    models = read_antex(atx)
    assert antenna_key("LEIAR25.R4      LEIT") == ("LEIAR25.R4", "LEIT")
    assert antenna_key("trm29659.00") == ("TRM29659.00", "NONE")
    m, note = find_antenna(models, "LEIAR25.R4      LEIT")
    assert m is models[("LEIAR25.R4", "LEIT")] and note is None
    m, note = find_antenna(models, "TRM29659.00     UNAV")
    assert m is models[("TRM29659.00", "NONE")] and "radome UNAV" in note and "TRM29659.00 NONE is used" in note
    assert find_antenna(models, "SEPCHOKE_B3E6   SPKE") == (None, None)


def test_bad_files_are_named_with_their_line(tmp_path, atx):
    bad = tmp_path / "bad.atx"
    bad.write_text("not an antex file\n")
    with pytest.raises(CdgpsError, match=r"bad.atx: not an ANTEX file"):
        read_antex(bad)
    for east, words in (("x.98", "expected numbers"), ("nan", "expected finite numbers")):   # a bad offset, its line
        lines = atx.read_text().splitlines()
        k = next(i for i, ln in enumerate(lines) if "NORTH / EAST / UP" in ln and "158.30" in ln)
        lines[k] = _label(f"      0.60{east:>10}    158.30", "NORTH / EAST / UP")
        bad.write_text("\n".join(lines) + "\n")
        with pytest.raises(CdgpsError, match=rf"bad.atx: line {k + 1}: NORTH / EAST / UP: {words}"):
            read_antex(bad)
    lines = atx.read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.startswith("   NOAZI") and i > 20)
    lines[k] = lines[k][:-8]                                              # one value short of the zenith grid
    bad.write_text("\n".join(lines) + "\n")
    with pytest.raises(CdgpsError, match=r"NOAZI row has 18 values, its zenith grid 0–90° by 5° has 19"):
        read_antex(bad)
    with pytest.raises(CdgpsError, match=r"cannot read"):
        read_antex(tmp_path / "missing.atx")
    lines = atx.read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if "LEIAR25.R4      LEIT" in ln)
    bad.write_text("\n".join(lines[:k + 6]) + "\n")                          # cut inside that antenna
    with pytest.raises(CdgpsError, match=rf"bad.atx: line {k}: antenna LEIAR25.R4 LEIT has no END OF ANTENNA"):
        read_antex(bad)
    bad.write_text("\n".join(lines[:2]) + "\n")                              # cut inside the header
    with pytest.raises(CdgpsError, match=r"bad.atx: no END OF HEADER"):
        read_antex(bad)
    k = next(i for i, ln in enumerate(lines) if "LEIAR25.R4      LEIT" in ln)
    bad.write_text("\n".join(lines[:k - 1]) + "\n")                          # only the satellite's entry
    with pytest.raises(CdgpsError, match=r"bad.atx: holds no receiver antenna type calibration"):
        read_antex(bad)


def test_placeholder_antenna_fields_name_no_antenna():
    """``ANT # / TYPE`` fields that fill the field without naming an antenna (blank, ``Unknown``, Spirent's
    ``ant_type``, gnss-sdr's ``Antenna type``) name none, so no "the antennas differ" warning is built on them."""
    from cdgps_cli.io.antex import header_antenna_type  # noqa: PLC0415
    from cdgps_cli.pipeline.antenna_models import mixed_antennas_note  # noqa: PLC0415

    for text in ("", "   ", "Unknown", "ant_type", "Antenna type", "ANTENNA  TYPE", "none"):
        assert header_antenna_type({"antenna_type": text}) is None, text
    assert header_antenna_type({"antenna_type": "TRM59800.80     SCIT"}) == "TRM59800.80 SCIT"
    headers = {"base": {"antenna_type": "ADVNULLANTENNA"}, "rover": {"antenna_type": "Antenna type"}}
    assert mixed_antennas_note(headers, {"base": "b.obs", "rover": "r.obs"}) == []
    headers["rover"]["antenna_type"] = "TRM59800.80 SCIT"
    assert len(mixed_antennas_note(headers, {"base": "b.obs", "rover": "r.obs"})) == 1
