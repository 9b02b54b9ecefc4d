"""Reading and writing measurement logs and data sets."""

from radioloc.io.logs import (
    LIMITS,
    check_kinds,
    check_output_path,
    read_anchors,
    read_measurements,
    write_estimates,
)

__all__ = ["LIMITS", "check_kinds", "check_output_path", "read_anchors", "read_measurements",
           "write_estimates"]
