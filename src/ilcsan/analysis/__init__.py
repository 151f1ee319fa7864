"""Analysis of runs: reports (the paper's reward tables beside its published numbers, curves) and the energy model."""
