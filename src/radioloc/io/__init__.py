"""Reading and writing measurement logs and data sets."""

from radioloc.io.datasets import export, fetch, read_table_text, write_table
from radioloc.io.logs import read_anchors, read_measurements, write_estimates

__all__ = ["export", "fetch", "read_anchors", "read_measurements", "read_table_text",
           "write_estimates", "write_table"]
