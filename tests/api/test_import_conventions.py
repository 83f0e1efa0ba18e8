"""Other labs' exports, as they write them (a new lab member's trial of 62 such files): units in the
column names, European spreadsheets, MATLAB comments, other encodings, rounded clocks. Each must
import with the right numbers in s, V and µm, or be refused naming the column at fault; a value a
piezo stage would hardly show is accepted with a note saying which unit may be meant."""

from __future__ import annotations

import codecs

import numpy as np
import pytest

from service.http.app import create_app
from service.runtime.settings import Settings
from service.science.data.datasets import DataError, parse_table
from tests.support.api_client import authed_client

FS = 1000.0
T = np.arange(3000) / FS
U = 50 - 50 * np.cos(2 * np.pi * T)  # V, 0–100 V at 1 Hz
X = 0.12 * U - 1.2 * np.sin(2 * np.pi * T)  # µm, a loop


def _text(header: str, columns, fmt: str = "{:.9f}", sep: str = ",", decimal: str = ".") -> str:
    rows = [sep.join(fmt.format(v).replace(".", decimal) for v in row) for row in zip(*columns)]
    return "\n".join(([header] if header else []) + rows) + "\n"


def _exact(table, t_s=T, u_v=U, x_um=X):
    np.testing.assert_allclose(table.arrays["u_y_v"], u_v, atol=1e-8)
    np.testing.assert_allclose(table.arrays["x_y_um"], x_um, atol=1e-8)
    assert table.sample_rate_hz == pytest.approx(1.0 / (t_s[1] - t_s[0]), rel=1e-9)


@pytest.mark.parametrize(
    "header, columns, mapping, converted",
    [
        (
            "Time [ms],Voltage (V),Displacement [nm]",
            (T * 1e3, U, X * 1e3),
            {"t": "Time [ms]", "u": "Voltage (V)", "x": "Displacement [nm]"},
            ["t", "x"],
        ),
        (
            "Time/s,Voltage/mV,Position/mm",
            (T, U * 1e3, X * 1e-3),
            {"t": "Time/s", "u": "Voltage/mV", "x": "Position/mm"},
            ["u", "x"],
        ),
        (
            "t in ms,u in V,x in um",
            (T * 1e3, U, X),
            {"t": 0, "u": 1, "x": 2},
            ["t"],
        ),  # by index: the header's unit holds
        ("t_ms,u_y_mv,x_y_nm", (T * 1e3, U * 1e3, X * 1e3), None, ["t", "u_y", "x_y"]),  # suffixes, without a mapping
        ("t [ms],u_y [V],x_y [pm]", (T * 1e3, U, X * 1e6), None, ["t", "x_y"]),
    ],
)
def test_units_in_column_names_are_converted_and_noted(header, columns, mapping, converted):
    """The trial's silent factors of 1000: 'Time [ms]' read as seconds, 'Displacement [nm]' as µm."""
    table = parse_table(_text(header, columns, fmt="{:.12g}").encode(), columns=mapping, axis="y")
    _exact(table)
    assert [n.split(":")[0] for n in table.notes] == converted, table.notes


def test_a_units_row_under_the_header_gives_the_units():
    table = parse_table(_text("t\tu_y\tx_y\ns\tV\tnm", (T, U, X * 1e3), sep="\t").encode())
    _exact(table)
    assert table.notes == [
        "file: a units row under the header (s, V, nm) gives the columns' units",
        "x_y: the units row's 'nm' gives nm; converted to µm (× 0.001)",
    ]


@pytest.mark.parametrize(
    "header, mapping, field, words",
    [
        ("t,u_y [V],x_y [V]", None, "x_y", "the header 'x_y [V]' gives a voltage unit, not one of length"),
        ("t,u_y,x_y [a.u.]", None, "x_y", "a unit this service does not know"),
        ("t,drive,pos [counts]", {"u": "drive", "x": "pos [counts]"}, "columns", '"scale": <µm per value>'),
        ("t,u,x", {"u": 1, "x": {"column": 2, "unit": "furlong"}}, "columns", "does not know"),
    ],
)
def test_a_unit_of_the_wrong_quantity_or_unknown_is_refused_naming_the_column(header, mapping, field, words):
    with pytest.raises(DataError) as info:
        parse_table(_text(header, (T, U, X)).encode(), columns=mapping, axis="y")
    assert info.value.field == field and words in info.value.message, info.value.message


def test_a_scale_in_the_mapping_is_the_whole_conversion():
    """Counts of a gauge with its own calibration: the mapping's scale, not the header's unit."""
    table = parse_table(
        _text("t,drive,pos [counts]", (T, U, X / 0.004)).encode(),
        columns={"t": 0, "u": 1, "x": {"column": 2, "scale": 0.004}},
        axis="y",
    )
    _exact(table)
    assert table.notes == []


@pytest.mark.parametrize(
    "header, scales",
    [
        ("Time [ms],Voltage (V),Displacement [nm]", (1e3, 1.0, 1e3)),
        ("time_s,drive_V,displacement_um", (1.0, 1.0, 1.0)),  # a new user's file, refused before
    ],
)
def test_a_header_of_words_whose_units_confirm_them_is_read(header, scales):
    """Another lab's header: each column named by a word (time, voltage, displacement) and a unit
    of that quantity. The unit confirms the word, so the file is read unasked (converted to the
    service's units), and the note says how each column was read; only the axis must be given."""
    content = _text(header, (T * scales[0], U * scales[1], X * scales[2])).encode()
    table = parse_table(content, axis="y")
    _exact(table)
    assert any(n.startswith("columns: read by their words, each confirmed by its unit") for n in table.notes)
    with pytest.raises(DataError) as info:
        parse_table(content)
    assert info.value.field == "axis"


def test_a_header_of_words_without_confirming_units_is_refused_with_the_mapping_it_suggests():
    """'Output (V)' is a voltage, not the displacement the word may mean; without units nothing
    confirms the words: refused, with the mapping to give."""
    with pytest.raises(DataError) as info:
        parse_table(_text("Time,Voltage,Displacement", (T, U, X)).encode())
    assert info.value.field == "file"
    assert 'give columns {"t": "Time", "u": "Voltage", "x": "Displacement"} and the axis' in info.value.message
    with pytest.raises(DataError) as info:
        parse_table(_text("time_s,input_V,output_V", (T, U, X)).encode(), axis="y")
    assert info.value.field == "file" and "no known columns" in info.value.message


@pytest.mark.parametrize(
    "content",
    [
        # a European spreadsheet: semicolons, decimal commas (with and without a header)
        _text("t;u_y;x_y", (T, U, X), sep=";", decimal=","),
        # and with a units row under the header (a new user's file: refused as "'0,000' is not a number")
        _text("t;u_y;x_y\nms;V;nm", (T * 1e3, U, X * 1e3), sep=";", decimal=","),
        # MATLAB/Octave comments before the header, Windows line endings
        ("% exported by MATLAB R2023b\r\n% stage 2, gauge 1\r\n" + _text("t,u_y,x_y", (T, U, X)).replace("\n", "\r\n")),
        # quoted numbers, a spreadsheet's trailing rows of empty fields
        _text('"t","u_y","x_y"', (T, U, X), fmt='"{:.9f}"') + ",,\n,,\n",
        # pandas' to_csv of an unnamed frame: a header of the column numbers (mapped by index)
        _text("0,1,2", (T, U, X)),
    ],
)
def test_spreadsheet_matlab_and_pandas_exports_import_with_their_numbers(content):
    mapping = {"t": 0, "u": 1, "x": 2} if content.startswith("0,1,2") else None
    table = parse_table(content.encode(), columns=mapping, axis="y")
    assert table.samples == T.size
    _exact(table)
    # how the file was read is said where it differs from the service's own CSV
    assert any("decimal commas" in n for n in table.notes) == content.startswith("t;u_y;x_y")


@pytest.mark.parametrize(
    "encoding, bom", [("utf-16-le", codecs.BOM_UTF16_LE), ("utf-16-be", codecs.BOM_UTF16_BE), ("latin-1", b"")]
)
def test_utf16_with_its_bom_and_latin1_files_are_read(encoding, bom):
    """Excel's "Unicode text" is UTF-16 with a BOM; an old Windows program writes µ as Latin-1."""
    content = bom + _text("t\tu_y [V]\tx_y [µm]", (T, U, X), sep="\t").encode(encoding)
    table = parse_table(content)
    _exact(table)
    assert table.notes == [f"file: read as {'UTF-16' if bom else 'LATIN-1'} text"]


def test_time_stamps_written_with_too_few_decimals_are_an_even_clock():
    t = np.arange(6000) / 3000.0  # 3 kHz written as 0.0003, 0.0007, 0.0010 s
    u, x = 50 - 50 * np.cos(2 * np.pi * t), 0.1 * (50 - 50 * np.cos(2 * np.pi * t))
    table = parse_table(_text("t,u_y,x_y", (np.round(t, 4), u, x), fmt="{:.4f}").encode())
    assert table.sample_rate_hz == pytest.approx(3000.0, rel=1e-6)
    jittered = np.round(t + np.random.default_rng(0).normal(0, 0.02 / 3000, t.size), 9)  # not rounding
    with pytest.raises(DataError) as info:
        parse_table(_text("t,u_y,x_y", (jittered, u, x)).encode())
    assert info.value.field == "t" and "give sample_rate_hz" in info.value.message


def test_unix_time_stamps_give_the_clock_exactly():
    table = parse_table(_text("t,u_y,x_y", (1.7e9 + T, U, X), fmt="{:.6f}").encode())
    assert table.sample_rate_hz == pytest.approx(1000.0, abs=1e-3)


def test_values_a_piezo_stage_would_hardly_show_are_kept_with_a_note_on_the_unit():
    """Measured data is not a command: nanometres under a plain x_y, or milliseconds under a plain t,
    are imported as written, and the note says which unit may be meant."""
    table = parse_table(_text("time,u_y,x_y", (T * 1e3, U, X * 1e3)).encode())
    assert table.sample_rate_hz == pytest.approx(1.0)
    assert any("x_y_nm" in n for n in table.notes) and any("t_ms" in n for n in table.notes), table.notes


def test_the_import_route_answers_the_notes_and_keeps_them(tmp_path):
    body = _text("Time [ms],Voltage (V),Displacement [nm]", (T * 1e3, U, X * 1e3)).encode()
    with authed_client(create_app(Settings(data_dir=tmp_path, bench="default", seed=0))) as http:
        r = http.post(
            "/api/datasets",
            files={"file": ("lab-b.csv", body, "text/csv")},
            data={"columns": '{"t": "Time [ms]", "u": "Voltage (V)", "x": "Displacement [nm]"}', "axis": "y"},
        )
        assert r.status_code == 201, r.text
        notes = r.json()["import_notes"]
        assert notes == [
            "t: the header 'Time [ms]' gives ms; converted to s (× 0.001)",
            "x: the header 'Displacement [nm]' gives nm; converted to µm (× 0.001)",
        ]
        assert http.get(f"/api/datasets/{r.json()['id']}").json()["import_notes"] == notes
        data = http.get(f"/api/datasets/{r.json()['id']}/data", params={"max_points": 10**6}).json()
        x = np.asarray(data.get("columns", data)["x_y_um"])
        np.testing.assert_allclose(x, X, atol=1e-8)
