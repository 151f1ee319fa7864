"""Grids of runs: the paper's tables, jobs, backends (local, Ray) and the coordinator of ``ilcsan reproduce``."""
