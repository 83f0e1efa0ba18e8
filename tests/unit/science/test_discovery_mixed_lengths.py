"""A creep model fits, predicts and diagnoses records of different lengths together (a sine sweep
plus a longer separating experiment), and a stored model predicts a record longer than its data."""

from __future__ import annotations

import numpy as np

from service.science.discovery.composite import CompositeModel


def test_creep_columns_do_not_depend_on_each_records_length(sweeps):
    short = sweeps("creep", seed=0, frequencies_hz=(50.0,), cycles=3, axes=("y",))["y"]
    long = sweeps("creep", seed=1, frequencies_hz=(10.0, 50.0), cycles=5, axes=("y",))["y"]
    assert long.n > 2 * short.n
    model = CompositeModel(["creep"]).fit([short, long])
    assert model.scales["time_scale_s"] == long.n / long.fs_hz
    for rec in (short, long):
        assert np.sqrt(np.mean((model.predict(rec) - rec.x_um) ** 2)) < 0.2 * np.ptp(rec.x_um)
    # A model fitted on the short record alone predicts the long one (same columns).
    alone = CompositeModel.from_dict(CompositeModel(["creep"]).fit([short]).to_dict())
    assert alone.predict(long).shape == long.x_um.shape
