"""A user's own task, registered the way a user's package registers one (``--task own_tasks:HeavyPendulum-v0``)."""

import gymnasium

gymnasium.register(id="HeavyPendulum-v0", entry_point="gymnasium.envs.classic_control.pendulum:PendulumEnv",
                   max_episode_steps=200, kwargs={"g": 12.0})
