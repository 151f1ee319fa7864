"""Proxy Target (Xu, Bu, Hao, Ding, Yu, NeurIPS 2025, arXiv 2505.24161) as declared: a continuous proxy actor, fitted
to the online actor before every update, gives TD3's target values. Training: :mod:`ilcsan.rl.methods.proxy_target`."""

from __future__ import annotations

from dataclasses import dataclass

from ..settings import setting
from .declaration import Declared, MethodProducts

PROXY_HIDDEN: tuple[int, ...] = (512, 512)
"""The proxy actor's hidden widths (ReLU MLP, tanh output): the default ``--proxy_hidden_sizes 512 512`` of the
Proxy Target code as reproduced in ``madao2333/Proxy-Target-with-PLIF`` (main.py)."""
COST_PER_ITERATION = 0.6
"""A training step's time grows by this fraction of a plain step per regression step (``proxy_iterations``)."""


class ProxyTargetDeclaration(Declared):
    kind, name, title = "target_actor", "proxy", "Proxy Target"
    paper = "Proxy Target: a continuous proxy fitted to the online actor (Xu et al., NeurIPS 2025, arXiv 2505.24161)"
    option_help = ("proxy, Proxy Target's continuous proxy imitating the online actor (Xu et al. 2025; spiking actors "
                   "only)")
    cost_note = f"1 + {COST_PER_ITERATION:g}·K"
    spiking_only = True
    spiking_reason = "it replaces a spiking target actor by a continuous proxy; DAN is continuous already"
    training = "ilcsan.rl.methods.proxy_target:ProxyTarget"

    @dataclass(frozen=True)
    class Settings:
        proxy_iterations: int = setting(3, "Proxy Target: regression steps of the proxy per TD3 update (K; 1 with "
                                           "--proxy-lr 3e-3 is the cheap setting)", minimum=1)
        proxy_lr: float = setting(1e-3, "Proxy Target: the proxy's Adam learning rate", bounds="positive")

    @classmethod
    def relative_cost(cls, training) -> float:
        return 1.0 + COST_PER_ITERATION * training.proxy_iterations

    @classmethod
    def products(cls, training, state_dim: int, action_dim: int, products: MethodProducts) -> None:
        """Per update: the online actor's forward over the K·B states of the K regression steps (their targets), the
        proxy's three products K times (its fit) and its forward once more, as π' giving the next actions in place
        of the actor's copy."""
        products.next_actions_by_actor = 0.0
        products.actor_forwards.append((training.batch_size * training.proxy_iterations, 1.0))
        products.networks.append(((state_dim, *PROXY_HIDDEN, action_dim), training.batch_size,
                                  float(training.proxy_iterations), 1.0))
