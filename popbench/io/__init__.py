"""Pose-graph files: reading (read), their line formats (format), the value ranges checked at load
(limits), writing (write). The public names of all four are importable from here.
"""

from popbench.io.format import MAX_VERTEX_ID
from popbench.io.limits import COORDINATE_LIMIT, INFORMATION_RANGE, INFORMATION_SPREAD
from popbench.io.read import ReadWarning, detect_format, read_graph, read_vertices
from popbench.io.write import (
    FLAGS_HEADER,
    GRAPH_WRITERS,
    file_ids,
    graph_writer,
    tum_rounded,
    write_flags,
    write_g2o,
    write_solution,
    write_toro,
    write_tum,
)

__all__ = [
    "COORDINATE_LIMIT",
    "FLAGS_HEADER",
    "GRAPH_WRITERS",
    "INFORMATION_RANGE",
    "INFORMATION_SPREAD",
    "MAX_VERTEX_ID",
    "ReadWarning",
    "detect_format",
    "file_ids",
    "graph_writer",
    "read_graph",
    "read_vertices",
    "tum_rounded",
    "write_flags",
    "write_g2o",
    "write_solution",
    "write_toro",
    "write_tum",
]
