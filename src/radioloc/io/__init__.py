"""Reading and writing measurement logs and data sets."""

from radioloc.io.logs import read_anchors, read_measurements, write_estimates

__all__ = ["read_anchors", "read_measurements", "write_estimates"]
