"""Reinforcement learning around the actor: TD3, replay, normalisation, tasks, evaluation, the training loop."""
