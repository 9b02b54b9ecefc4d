"""The Measurements table: schema round trip, selection, grids."""

import numpy as np
import pandas as pd
import pytest

from radioloc.core.errors import InputError
from radioloc.io.measurements import Measurements


def table():
    return Measurements.from_arrays(
        time=[0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 2.0],
        node=["t1", "t1", "t2", "t1", "t1", "t1", "t2"],
        peer=["A", "B", "A", "A", "A", "B", "B"],
        kind=["range", "range", "range", "range", "range", "aoa", "range"],
        value=[1.0, 2.0, 3.0, 4.0, 6.0, 0.5, 7.0],
        std=[np.nan, 0.2, np.nan, np.nan, np.nan, 0.1, np.nan])


def test_grid_averages_duplicates_and_leaves_nan_where_missing():
    g = table().grid("range", "t1")
    assert g.peers == ["A", "B"] and list(g.time) == [0.0, 1.0]
    np.testing.assert_array_equal(g.value, [[1.0, 2.0], [5.0, np.nan]])
    assert g.std[0, 1] == 0.2 and np.isnan(g.std[0, 0])


def test_grids_of_several_kinds_share_the_node_time_steps():
    m = table()
    assert m.grid("range", "t1").time.shape == m.grid("aoa", "t1").time.shape == (2,)


def test_round_trip_through_the_csv_schema(tmp_path):
    m = table()
    m.write(tmp_path / "m.csv")
    back = Measurements.read(tmp_path / "m.csv")
    pd.testing.assert_frame_equal(back.to_frame(), m.to_frame(), check_dtype=False)


def test_select_and_mask():
    m = table()
    assert m.select(kind="aoa").nodes == ["t1"] and m.kinds == ["aoa", "range"]
    f = m.frame.assign(mask=m.frame["node"] != "t2")
    assert Measurements(f).nodes == ["t1"]


def test_bad_input_names_the_column():
    with pytest.raises(InputError, match="value"):
        Measurements(pd.DataFrame({"time": [0.0], "node": ["a"], "peer": ["b"], "kind": ["range"]}))
    with pytest.raises(InputError, match="'value'"):
        Measurements.from_arrays(0.0, "a", "b", "range", np.array([1 + 2j]))
    with pytest.raises(InputError, match="mask"):
        Measurements.from_arrays(0.0, "a", "b", "range", [1.0], mask=np.array([1]))
    with pytest.raises(InputError, match="time grid"):
        table().grid("range", "t1", times=np.array([0.0]))
