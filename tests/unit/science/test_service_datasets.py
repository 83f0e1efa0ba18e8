"""Table import (the dataset CSV, headerless files with a mapping, the real yan9a-dbo data) and export."""

from __future__ import annotations

import io
import json

import h5py
import numpy as np
import pytest

from service.science.data.datasets import DataError, parse_table
from service.science.data.export import to_csv, to_hdf5
from service.science.data.segmentation import blocks_without_table
from tests.support.realdata import MODEL_VI_DO as REAL


def _csv(n=200, fs=1000.0, header="t,u_y,x_y", extra=None):
    t = np.arange(n) / fs
    u = 60 - 60 * np.cos(2 * np.pi * 10 * t)
    rows = [f"{a:.6f},{b:.6f},{0.05 * b:.6f}" for a, b in zip(t, u)]
    if extra:
        rows[extra[0]] = extra[1]
    return (header + "\n" + "\n".join(rows) + "\n").encode()


def test_real_piezo_data_imports_with_a_column_mapping():
    table = parse_table(
        REAL.read_bytes(), columns={"u": 0, "x": 4}, axis="y", sample_rate_hz=200, delimiter="whitespace"
    )
    assert table.axes == ["y"] and table.sample_rate_hz == 200 and table.samples == 8027
    raw = np.loadtxt(REAL)
    np.testing.assert_array_equal(table.arrays["u_y_v"], raw[:, 0])
    np.testing.assert_array_equal(table.arrays["x_y_um"], raw[:, 4])
    assert table.arrays["t_s"][-1] == pytest.approx(8026 / 200)
    [block] = blocks_without_table({"y": table.arrays["u_y_v"]}, 200)
    assert block["frequency_hz"] == pytest.approx(1.0, rel=1e-3)  # the README: 1 Hz drive
    assert block["cycles"] == 40 and (block["start"], block["stop"]) == (0, 8027)


def test_contract_csv_round_trips_through_export():
    table = parse_table(_csv())
    assert table.axes == ["y"] and table.sample_rate_hz == pytest.approx(1000.0)
    again = parse_table(to_csv(table.arrays).encode())
    for name in ("t_s", "u_y_v", "x_y_um"):
        np.testing.assert_allclose(again.arrays[name], table.arrays[name], rtol=1e-8)


def test_single_axis_file_with_axis_and_scaled_mapping():
    body = "\n".join(f"{k} {0.01 * k} {5 + k}" for k in range(50)).encode()
    table = parse_table(body, columns={"u": {"column": 1, "scale": 100.0}, "x": 2}, axis="z", sample_rate_hz=50)
    assert table.axes == ["z"]
    np.testing.assert_allclose(table.arrays["u_z_v"], np.arange(50.0))


@pytest.mark.parametrize(
    "content, kwargs, field, words",
    [
        (b"", {}, "file", "empty"),
        (b"\n  \n", {}, "file", "empty"),
        (_csv(extra=(5, "0.005,1.0")), {}, "file", "line 7 has 2 fields"),
        (_csv(extra=(5, "0.005,abc,1")), {}, "file", "'abc' is not a number"),
        (_csv(extra=(5, "0.005,nan,1")), {}, "u_y", "NaN"),
        (_csv(header="time_ms,drive,pos"), {}, "file", "no known columns"),
        (_csv(header="Time_ms,Drive,Pos"), {}, "file", "['Time_ms', 'Drive', 'Pos']"),  # as written
        (_csv(header="Time_ms,Drive_V,Pos_um"), {}, "axis", "needs axis set"),  # read by its units: which axis?
        (
            _csv(header="T,U_V,X_um"),
            {"columns": {"u": "U_V", "x": "Pos"}, "axis": "y"},
            "columns",
            "no column named 'Pos' in the header ['T', 'U_V', 'X_um']",
        ),
        (_csv(header="t,u,x"), {}, "axis", "axis"),
        (_csv().split(b"\n", 1)[1], {}, "columns", "no header row"),
        (_csv(), {"columns": "{u: 0"}, "columns", "not valid JSON"),
        (_csv(), {"columns": {"u": 1, "x": 7}, "axis": "y"}, "columns", "column 7 does not exist"),
        (_csv(), {"columns": {"u": 1, "speed": 2}, "axis": "y"}, "columns", "unknown column name"),
        (_csv(), {"columns": {"u": 1}, "axis": "y"}, "columns", "x_y is missing"),
        (_csv(), {"columns": {"u": 1, "x": 2}, "axis": "y"}, "sample_rate_hz", "no time column"),
        (_csv(), {"sample_rate_hz": 500}, "sample_rate_hz", "disagrees"),
        (_csv(extra=(5, "0.0041,1,1")), {}, "t", "evenly spaced"),
        (_csv(), {"delimiter": "pipe"}, "delimiter", "unknown delimiter"),
        (b"\xff\xfe\x00", {}, "file", "not valid UTF-16 text"),  # a BOM, then half a character
        (b"PK\x03\x04\x14\x00\x06\x00", {}, "file", "binary"),  # an .xlsx (a zip)
    ],
)
def test_bad_tables_name_the_field_at_fault(content, kwargs, field, words):
    with pytest.raises(DataError) as info:
        parse_table(content, **kwargs)
    assert info.value.field == field
    assert words in str(info.value)


def test_hdf5_export_carries_units_and_metadata():
    table = parse_table(_csv())
    blob = to_hdf5(table.arrays, {"sample_rate_hz": 1000.0, "blocks": [{"index": 0}], "partial": False, "plan": None})
    with h5py.File(io.BytesIO(blob), "r") as handle:
        assert handle["x_y_um"].attrs["unit"] == "µm" and handle["u_y_v"].attrs["unit"] == "V"
        np.testing.assert_array_equal(handle["u_y_v"][()], table.arrays["u_y_v"])
        assert handle.attrs["sample_rate_hz"] == 1000.0 and json.loads(handle.attrs["blocks"]) == [{"index": 0}]
        assert "plan" not in handle.attrs


def test_a_record_without_a_table_gets_one_block_or_its_steady_stretches():
    fs = 1000.0
    t = np.arange(5000) / fs
    [sine] = blocks_without_table({"y": 60 - 60 * np.cos(2 * np.pi * 4 * t)}, fs)
    assert sine["frequency_hz"] == pytest.approx(4.0, rel=1e-3) and sine["cycles"] == 20
    [ramp] = blocks_without_table({"y": np.linspace(0, 120, 5000)}, fs)
    assert ramp["frequency_hz"] is None and (ramp["start"], ramp["stop"]) == (0, 5000)
    chirp = blocks_without_table({"y": 60 - 60 * np.cos(2 * np.pi * (1 * t + 2 * t**2))}, fs)
    freqs = [b["frequency_hz"] for b in chirp]  # stretches of a slowly rising frequency
    assert len(chirp) >= 2 and freqs == sorted(freqs) and 1.0 < freqs[0] < freqs[-1] < 21.0
