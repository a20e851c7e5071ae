"""Plant topology: the graph of nodes and lane segments, its file formats and the sample plants (issue 3)."""
