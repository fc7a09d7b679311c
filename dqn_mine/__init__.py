"""dqn_mine: Ape-X style distributed deep Q-learning for a first-person 3D mine rescue task."""

__version__ = "0.1.0"

from dqn_mine.env import register_envs as _register_envs

_register_envs()


def load_agent(path, epsilon: float = 0.0, seed: int = 0, unstick: bool = False,
               held: bool = False):
    """A trained agent from a run folder or ``checkpoint.pt``: ``agent.predict(obs, info)`` gives
    an action, ``agent.reset()`` starts an episode. ``unstick``: a random action after a step
    that left the frame unchanged (or, with the run's ``--unstick k``, brought back one of the
    last k frames), as the run's training actors act. ``held``: random actions (epsilon's and
    unstick's) held for ez durations, as ez training actors hold them.
    A missing or corrupt checkpoint raises ``CheckpointError`` (a ValueError) with a one-line
    message."""
    from dqn_mine.agent.policy import AgentPolicy

    return AgentPolicy.from_checkpoint(path, epsilon=epsilon, seed=seed, unstick=unstick,
                                       held=held)
