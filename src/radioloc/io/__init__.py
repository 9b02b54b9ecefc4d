"""Reading and writing measurement logs and data sets."""

from radioloc.io.datasets import export, fetch, read_table_text, write_table
from radioloc.io.logs import (
    LIMITS,
    check_kinds,
    check_output_path,
    read_anchors,
    read_measurements,
    write_estimates,
)

__all__ = ["LIMITS", "check_kinds", "check_output_path", "export", "fetch", "read_anchors",
           "read_measurements", "read_table_text", "write_estimates", "write_table"]
