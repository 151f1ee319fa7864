"""The planned network (:mod:`.plan`) as Lava processes, run in Lava's simulator of Loihi 2.

``LavaActor(actor, fixed=...)`` builds one ``RingBuffer`` (the encoder's spikes and the clocks), a ``Dense`` per
projection and an ``LIF`` per population; ``act(observation)`` runs one block of B steps with the host's encoder
spikes, reads the LI voltages V_1..V_T (only V_T for D_last) and applies the statistic and tanh on the host, then
sets every state back to zero for the next action. Floating point runs ``Loihi2SimCfg(select_tag="floating_pt")``;
fixed point the bit-accurate models (``select_tag="fixed_pt"``) with the integer formats of
:class:`~.plan.FixedPlan`.

Needs ``lava-nc`` (Python 3.10; ``scripts/setup-lava``).
"""

from __future__ import annotations

import numpy as np
from lava.magma.core.run_conditions import RunSteps
from lava.magma.core.run_configs import Loihi2SimCfg
from lava.proc.dense.process import Dense
from lava.proc.io.source import RingBuffer
from lava.proc.lif.process import LIF
from lava.proc.monitor.process import Monitor
from lava.utils.weightutils import SignMode

from ...runtime import DeployedActor
from .plan import (
    DECODER,
    INPUT,
    NEVER,
    STATE_SHIFT,
    THRESHOLD_LIMIT,
    FixedPlan,
    encoder_spikes,
    fix_plan,
    host_action,
    plan_actor,
)


class LavaActor:
    """A deployed actor in Lava (see the module docstring); ``close()`` stops Lava's runtime."""

    def __init__(self, actor: DeployedActor, fixed: bool = False, calibration: list[np.ndarray] | None = None,
                 monitor_steps: int = 0):
        self.actor, self.plan = actor, plan_actor(actor)
        self.fixed: FixedPlan | None = fix_plan(self.plan, calibration or []) if fixed else None
        self.config = Loihi2SimCfg(select_tag="fixed_pt" if fixed else "floating_pt")
        self.source = RingBuffer(data=self._block_data(np.zeros((self.plan.timesteps, self.plan.encoded_width))))
        self.populations = {population.name: self._population(population) for population in self.plan.populations}
        self.denses = []
        for index, projection in enumerate(self.plan.projections):
            dense = self._dense(index, projection)
            sender = self.source.s_out if projection.source == INPUT else self.populations[projection.source].s_out
            sender.connect(dense.s_in)
            dense.a_out.connect(self.populations[projection.target].a_in)
            self.denses.append(dense)
        self.monitors = {}
        for name in (population.name for population in self.plan.populations[:-1]) if monitor_steps else ():
            self.monitors[name] = Monitor()
            self.monitors[name].probe(self.populations[name].s_out, monitor_steps)
        self.started = False

    # ------------------------------------------------------------------------------------------ building
    def _block_data(self, encoded: np.ndarray) -> np.ndarray:
        data = self.plan.source(encoded)
        return data.astype(np.int32) if self.fixed is not None else data

    def _population(self, population) -> LIF:
        size = (population.size,)
        if self.fixed is None:
            return LIF(shape=size, du=population.du, dv=population.dv, vth=population.threshold, bias_mant=0.0,
                       name=population.name)
        name = population.name
        return LIF(shape=size, du=self.fixed.du[name], dv=self.fixed.dv[name],
                   vth=THRESHOLD_LIMIT if population.threshold == NEVER else self.fixed.thresholds[name],
                   bias_mant=0, bias_exp=0, name=name)

    def _dense(self, index: int, projection) -> Dense:
        if self.fixed is None:
            return Dense(weights=projection.weights)
        return Dense(weights=self.fixed.weights[index], weight_exp=self.fixed.exponents[index], num_weight_bits=8,
                     sign_mode=SignMode.MIXED)

    # ------------------------------------------------------------------------------------------- running
    def _run(self, steps: int) -> None:
        self.source.run(condition=RunSteps(num_steps=steps), run_cfg=self.config)
        self.started = True

    def voltages(self, encoded: np.ndarray, every_step: bool = True) -> np.ndarray:
        """One block for encoder spikes (T, D_0): the LI voltages V_1..V_T (T, M) in float units (``every_step``
        False: only V_T, as (1, M), one run call fewer per step)."""
        if self.started:
            self.source.data.set(self._block_data(encoded))
        else:  # Lava sets a Var only while its runtime runs: the first block is the data it compiles with
            self.source.data.init = self._block_data(encoded)
        decoder = self.populations[DECODER]
        readouts = self.plan.readout_steps if every_step else self.plan.readout_steps[-1:]
        readings, done = [], 0
        for step in readouts:
            self._run(step - done)
            done = step
            readings.append(decoder.v.get())
        if done < self.plan.block:
            self._run(self.plan.block - done)
        self._reset()
        scale = self.fixed.units[DECODER] / 2 ** STATE_SHIFT if self.fixed is not None else 1.0
        return np.array(readings, np.float64) * scale

    def _reset(self) -> None:
        """Every state back to zero, as Algorithm 1 starts each action (V_0 = C_0 = 0, no spikes in flight). The
        Denses from the input hold nothing after a block (its last column is silent)."""
        kind = np.int32 if self.fixed is not None else np.float64
        for population in self.plan.populations:
            process = self.populations[population.name]
            process.u.set(np.zeros(population.size, kind))
            process.v.set(np.zeros(population.size, kind))
        for dense, projection in zip(self.denses, self.plan.projections, strict=True):
            if projection.source != INPUT:
                dense.a_buff.set(np.zeros(projection.weights.shape[0], kind))

    def act(self, observation: np.ndarray) -> np.ndarray:
        """The action for one raw observation (N,) → (M,): host encoder, Lava network, host statistic and tanh."""
        every_step = str(self.actor.meta["statistic"]) != "last"
        return host_action(self.actor, self.voltages(encoder_spikes(self.actor, observation), every_step))

    def spike_counts(self) -> dict[str, int]:
        """Spikes each monitored layer emitted in its T steps of every block so far (``monitor_steps`` > 0, a
        multiple of the block). Layer l's step t is Lava step t + l of a block; spikes after step T + l (from the
        charge left before the reset) reach no readout and are not counted."""
        counts, plan = {}, self.plan
        for index, (name, monitor) in enumerate(self.monitors.items(), start=1):
            spikes = np.asarray(next(iter(monitor.get_data().values()))["s_out"])
            blocks = spikes[:spikes.shape[0] // plan.block * plan.block].reshape(-1, plan.block, spikes.shape[-1])
            counts[name] = int(np.count_nonzero(blocks[:, index:index + plan.timesteps]))
        return counts

    def close(self) -> None:
        if self.started:
            self.source.stop()
            self.started = False

