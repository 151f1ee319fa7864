"""Analysis of runs: the paper's published numbers, reports (tables, curves) and the energy model."""
