"""dqn_mine: Ape-X style distributed deep Q-learning for a first-person 3D mine rescue task."""

__version__ = "0.1.0"

from dqn_mine.env import register_envs as _register_envs

_register_envs()
