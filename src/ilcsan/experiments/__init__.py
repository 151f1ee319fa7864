"""Grids of runs: the paper's tables or a user's grid file expanded into runs, jobs, backends (local, Ray) and the
coordinator of ``ilcsan reproduce``."""
