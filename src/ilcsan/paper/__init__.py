"""The paper as data, at the bottom of the package: what it printed and how its tables are run.

* :mod:`.published`: the paper's numbers as printed (tasks, reward tables with their APR, firing rates, operation
  counts, energy), transcribed by hand;
* :mod:`.layouts`: each reward table as a grid of runs (tasks × rows × seeds, the evaluation protocol, each row's
  actor), with our ``beyond``, ``algorithms`` and ``fidelity`` grids beside them.

Both import nothing from ilcsan but :mod:`ilcsan.config` and :mod:`ilcsan.errors`, so the tasks
(:mod:`ilcsan.rl.tasks`), the grids (:mod:`ilcsan.experiments`) and the reports (:mod:`ilcsan.analysis`) all read
them from here.
"""
