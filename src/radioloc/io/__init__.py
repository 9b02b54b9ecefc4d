"""Reading and writing measurement logs and data sets."""

from radioloc.io.datasets import export, fetch, read_table_text, write_table
from radioloc.io.logs import (
    LIMITS,
    check_kinds,
    check_output_path,
    range_arrays,
    read_cells,
    read_anchors,
    read_measurements,
    read_reference,
    write_estimates,
)

from radioloc.io.hanyang import authors_reference, authors_rmse, authors_window, measurement_rows
from radioloc.io.ujiindoorloc import UjiScans, load_split, read_scans

__all__ = ["authors_rmse", "authors_window", "authors_reference", "measurement_rows", "UjiScans", "load_split", "read_scans", "read_cells", "LIMITS", "check_kinds", "check_output_path", "export", "fetch", "read_anchors",
           "range_arrays", "read_measurements", "read_reference", "read_table_text", "write_estimates", "write_table"]
