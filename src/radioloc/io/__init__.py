"""Reading and writing measurement logs and data sets."""

from radioloc.core.lazy import lazy_exports

#: public name -> the submodule defining it (imported on first access)
_WHERE = {
    "export": "datasets",
    "fetch": "datasets",
    "read_table_text": "datasets",
    "write_table": "datasets",
    "LIMITS": "logs",
    "check_kinds": "logs",
    "read_cells": "logs",
    "read_anchors": "logs",
    "read_measurements": "logs",
    "read_reference": "logs",
    "write_estimates": "logs",
    "authors_reference": "hanyang",
    "authors_rmse": "hanyang",
    "authors_window": "hanyang",
    "measurement_rows": "hanyang",
    "UjiScans": "ujiindoorloc",
    "load_split": "ujiindoorloc",
    "read_scans": "ujiindoorloc",
}
__getattr__, __dir__ = lazy_exports(__name__, _WHERE)

__all__ = ["authors_rmse", "authors_window", "authors_reference", "measurement_rows", "UjiScans", "load_split", "read_scans", "read_cells", "LIMITS", "check_kinds", "export", "fetch", "read_anchors",
           "read_measurements", "read_reference", "read_table_text", "write_estimates", "write_table"]
