"""CaRe-BN's normalisation of a spiking actor's synaptic currents (Xu et al., ICLR 2026), the actor's side.

Each synaptic layer's current X = W S + b, shape (K, T, B, D) (or (K, B, D) when the input is the same at every
step), is normalised per seed k and neuron d before the neuron update, with statistics pooled over the batch and all
T steps:

  X̂ = γ (X − μ) / √(σ² + ε) + β,        μ, σ² (K, D); γ, β (K, D), both initialised to V_th / 2.

σ² is the biased (population) variance of the B·T values, as the authors' code computes it. On ILC-SAN's output
populations only this feed-forward current is normalised; the intra-layer current of Eq. (10) is added after it.
PopSAN's decoder (and ILC-SAN's LI decoder) are not normalised: the normalised layers are those before a spiking
neuron update.

Which (μ, σ²) a layer uses:

* in the actor's loss, the batch's own, :func:`batch_statistics` (gradients flow through them);
* everywhere else (acting, evaluation, the target actor), the running statistics μ̂, σ̂² the layer holds. How they
  are estimated (a Kalman-style gain after each batch-statistics pass, a periodic recalibration on replayed states)
  is CaRe-BN's training, :mod:`ilcsan.rl.methods.care_bn`: the actor only holds them and normalises with them.

With fixed statistics the normalisation is an affine map X̂ = s X + h (:func:`norm_affine`), which
:func:`fold_into_linear` moves into the layer's weight and bias, so an exported actor stays additions-only.

Every function here is pure (new tensors out, nothing changed in place). :class:`CareBatchNorm` holds one layer's
γ, β (parameters) and μ̂, σ̂², P_μ, P_σ² (persistent buffers, ensemble dimension K first) and applies them.
:class:`LayerNormalizations` is what an actor holds: one such module per synaptic layer, built from the class a
normalisation's declaration names, with the choice of statistics of each pass (:data:`StatisticsChoice`) and the
export fold (:meth:`LayerNormalizations.export_fold`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import torch
from torch import nn

from ..errors import UserError

EPSILON = 1e-5
"""ε in √(σ² + ε), the authors' value."""
RUNNING_BUFFERS = ("running_mean", "running_var", "mean_innovation", "var_innovation")
"""The names of :class:`CareBatchNorm`'s persistent buffers μ̂, σ̂², P_μ, P_σ², in :class:`RunningStatistics`'
order."""


class NormStatistics(NamedTuple):
    """Per seed and neuron mean μ and biased variance σ², each (K, D)."""

    mean: torch.Tensor
    var: torch.Tensor


StatisticsChoice = str | Sequence[NormStatistics]
"""Which statistics a normalising actor's layers use in one pass: "running" (the default), "batch" (each layer its
batch's own, pooled over the batch and the T steps), or a sequence of :class:`NormStatistics` for the first layers,
the layers after them using their batch's own ("batch" is the empty sequence)."""


class RunningStatistics(NamedTuple):
    """The running statistics μ̂, σ̂² and the tracked variances P_μ, P_σ² of their innovations, each (K, D)."""

    mean: torch.Tensor
    var: torch.Tensor
    mean_innovation: torch.Tensor
    var_innovation: torch.Tensor


def batch_statistics(currents: torch.Tensor) -> NormStatistics:
    """μ and the biased σ² of currents (K, ..., D) over every dimension but the first (seed) and last (neuron): for
    (K, T, B, D) pooled over the T steps and the B states. A (K, B, D) current that is the same at every step has the
    same pooled statistics as its T copies. Differentiable: the actor's loss backpropagates through them."""
    var, mean = torch.var_mean(currents, dim=tuple(range(1, currents.dim() - 1)), correction=0)
    return NormStatistics(mean, var)


def _per_neuron(values: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """(K, D) reshaped to broadcast against ``like`` (K, ..., D)."""
    return values.reshape(values.shape[0], *([1] * (like.dim() - 2)), values.shape[-1])


def norm_affine(statistics: NormStatistics, gamma: torch.Tensor, beta: torch.Tensor,
                eps: float = EPSILON) -> tuple[torch.Tensor, torch.Tensor]:
    """The normalisation as the affine map X̂ = s X + h: s = γ / √(σ² + ε), h = β − s μ, each (K, D)."""
    scale = gamma * torch.rsqrt(statistics.var + eps)
    return scale, beta - scale * statistics.mean


def normalize(currents: torch.Tensor, statistics: NormStatistics, gamma: torch.Tensor, beta: torch.Tensor,
              eps: float = EPSILON) -> torch.Tensor:
    """X̂ = γ (X − μ) / √(σ² + ε) + β for currents (K, ..., D), computed as s X + h (:func:`norm_affine`)."""
    scale, shift = norm_affine(statistics, gamma, beta, eps)
    return currents * _per_neuron(scale, currents) + _per_neuron(shift, currents)


def fold_into_linear(weight: torch.Tensor, bias: torch.Tensor | None, statistics: NormStatistics,
                     gamma: torch.Tensor, beta: torch.Tensor,
                     eps: float = EPSILON) -> tuple[torch.Tensor, torch.Tensor]:
    """The weight (K, D, in) and bias (K, D) of one layer whose output W S + b is normalised with fixed
    ``statistics``: with s = γ / √(σ² + ε), W' = s W (row d scaled by s_d) and b' = s (b − μ) + β, so that
    W' S + b' = γ (W S + b − μ) / √(σ² + ε) + β. A layer without bias folds as b = 0."""
    scale, shift = norm_affine(statistics, gamma, beta, eps)
    folded_bias = shift if bias is None else scale * bias + shift
    return scale.unsqueeze(-1) * weight, folded_bias


class CareBatchNorm(nn.Module):
    """CaRe-BN of one synaptic layer's current for K seeds and D neurons.

    γ, β (K, D) are parameters, initialised to V_th / 2 (``threshold``). The buffers ``running_mean`` (0),
    ``running_var`` (1), ``mean_innovation`` and ``var_innovation`` (P_μ, P_σ², both 0) are persistent, K first.
    ``forward`` normalises with the statistics it is given, else the running ones; the ``_``-suffixed methods write
    the buffers in place.
    """

    def __init__(self, ensemble: int, features: int, threshold: float, eps: float = EPSILON):
        super().__init__()
        self.threshold, self.eps = threshold, eps
        self.gamma = nn.Parameter(torch.empty(ensemble, features))
        self.beta = nn.Parameter(torch.empty(ensemble, features))
        for name in RUNNING_BUFFERS:
            self.register_buffer(name, torch.empty(ensemble, features))
        self.reset_parameters()

    def reset_parameters(self) -> None:
        """γ = β = V_th / 2, μ̂ = 0, σ̂² = 1, P_μ = P_σ² = 0 (the authors' initial values)."""
        with torch.no_grad():
            self.gamma.fill_(self.threshold / 2.0)
            self.beta.fill_(self.threshold / 2.0)
            self.running_mean.zero_()
            self.running_var.fill_(1.0)
            self.mean_innovation.zero_()
            self.var_innovation.zero_()

    def running(self) -> NormStatistics:
        """The running statistics (μ̂, σ̂²) as a layer normalises with them."""
        return NormStatistics(self.running_mean, self.running_var)

    def running_state(self) -> RunningStatistics:
        """μ̂, σ̂², P_μ, P_σ²: what CaRe-BN's Kalman update reads and writes
        (:func:`~ilcsan.rl.methods.care_bn.kalman_update`)."""
        return RunningStatistics(self.running_mean, self.running_var, self.mean_innovation, self.var_innovation)

    def forward(self, currents: torch.Tensor, statistics: NormStatistics | None = None) -> torch.Tensor:
        """Currents (K, ..., D) normalised with ``statistics``, or with the running statistics when None."""
        return normalize(currents, self.running() if statistics is None else statistics, self.gamma, self.beta,
                         self.eps)

    @torch.no_grad()
    def set_running_(self, statistics: NormStatistics) -> None:
        """Replace μ̂, σ̂² (recalibration); P_μ, P_σ² are kept, as in the authors' code."""
        self.running_mean.copy_(statistics.mean)
        self.running_var.copy_(statistics.var)

    def folded_linear(self, tensors: dict[str, torch.Tensor], weight: torch.Tensor,
                      bias: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
        """:func:`fold_into_linear` of the layer ``weight``, ``bias`` with this module's exported ``tensors`` (its
        parameters and buffers by their own names, as an export reads them): what the export fold of
        :class:`LayerNormalizations` does per layer."""
        statistics = NormStatistics(tensors["running_mean"], tensors["running_var"])
        return fold_into_linear(weight, bias, statistics, tensors["gamma"], tensors["beta"], self.eps)

    def extra_repr(self) -> str:
        k, d = self.gamma.shape
        return f"ensemble={k}, features={d}, eps={self.eps}"


class LayerNormalizations(nn.ModuleList):
    """The normalisation of each synaptic layer of an actor: ``layer(ensemble, width, threshold)`` per layer width,
    ``layer`` the module class a normalisation's declaration names (:class:`CareBatchNorm` for CaRe-BN), whose
    instances normalise with the statistics they are given (``forward(currents, statistics)``), hold running ones
    (``running()``, ``set_running_(statistics)``) and fold into their layer (``folded_linear``). ``normalizes`` is the
    name of the actor's list of synaptic layers, whose layer l the module l normalises (for the export fold)."""

    def __init__(self, layer: type[nn.Module], ensemble: int, widths: Sequence[int], threshold: float,
                 normalizes: str = "layers"):
        super().__init__(layer(ensemble, width, threshold) for width in widths)
        self.normalizes = normalizes

    def reset_parameters(self) -> None:
        for norm in self:
            norm.reset_parameters()

    def statistics_of(self, index: int, currents: torch.Tensor,
                      choice: str | tuple[NormStatistics, ...]) -> NormStatistics:
        """The statistics layer ``index`` normalises its ``currents`` with under a checked ``choice``
        (:func:`checked_statistics`): the running ones, the given ones, or the batch's own."""
        if choice == "running":
            return self[index].running()
        return choice[index] if index < len(choice) else batch_statistics(currents)

    def set_running_(self, statistics: Sequence[NormStatistics]) -> None:
        """Replace each layer's running μ̂, σ̂² (P_μ, P_σ² are kept), in place."""
        for norm, layer_statistics in zip(self, statistics, strict=True):
            norm.set_running_(layer_statistics)

    def export_fold(self, state: dict[str, torch.Tensor], prefix: str) -> dict[str, torch.Tensor]:
        """The exported ``state`` (names → tensors of one seed) with each normalisation ``<prefix>.<l>`` folded into
        the synaptic layer ``<normalizes>.<l>`` whose current it normalises (W' = s W, b' = s (b − μ̂) + β,
        :func:`fold_into_linear`) and its tensors (γ, β and the buffers) removed: the export of an actor with
        normalisation is an actor without, additions-only (:func:`ilcsan.deploy.state.fold_buffers`)."""
        for index, norm in enumerate(self):
            own = f"{prefix}.{index}."
            tensors = {name[len(own):]: tensor for name, tensor in state.items() if name.startswith(own)}
            layer = f"{self.normalizes}.{index}"
            weight, bias = norm.folded_linear(tensors, state[f"{layer}.weight"], state.get(f"{layer}.bias"))
            kept = {name: tensor for name, tensor in state.items() if not name.startswith(own)}
            state = {**kept, f"{layer}.weight": weight, f"{layer}.bias": bias}
        return state


def checked_statistics(norms: LayerNormalizations | None, choice: StatisticsChoice) -> str | tuple[NormStatistics, ...]:
    """``choice`` (:data:`StatisticsChoice`) as "running" or a tuple of given statistics ("batch": ()), or a
    :class:`UserError` when it is not one, or the actor (its ``norms``, None without normalisation) cannot use it."""
    if isinstance(choice, str) and choice not in ("running", "batch"):
        raise UserError(f"statistics {choice!r} is not one of: running, batch, or a sequence of statistics")
    if norms is None:
        if choice != "running":
            raise UserError("this actor does not normalise its currents (--normalization none): it has no "
                            "batch statistics to use")
        return "running"
    if choice == "running":
        return choice
    given = () if choice == "batch" else tuple(choice)
    if len(given) > len(norms):
        raise UserError(f"{len(given)} layers' statistics given, the actor has {len(norms)} layers")
    return given
