"""The first-person 3D mine rescue environment, registered as ``dqn_mine/MineRescue-v0``.

Importing this package does not create a GL context; the first render of a process does.
"""

ENV_ID = "dqn_mine/MineRescue-v0"


def register_envs() -> None:
    """Register ``dqn_mine/MineRescue-v0`` with gymnasium (idempotent).

    No ``max_episode_steps`` here: the environment truncates itself, so ``gymnasium.make(ENV_ID,
    max_episode_steps=...)`` reaches the environment and the raw class behaves like the made one.
    """
    import gymnasium

    if ENV_ID not in gymnasium.registry:
        gymnasium.register(ENV_ID, entry_point="dqn_mine.env.tasks:MineRescueEnv")


def __getattr__(name):
    # Lazy, so that `import dqn_mine` stays light; `from dqn_mine.env import MineRescueEnv` works.
    if name == "MineRescueEnv":
        from dqn_mine.env.tasks import MineRescueEnv

        return MineRescueEnv
    if name == "TASKS":
        from dqn_mine.env.tasks import TASKS

        return TASKS
    raise AttributeError(f"module 'dqn_mine.env' has no attribute {name!r}")


__all__ = ["ENV_ID", "register_envs", "MineRescueEnv", "TASKS"]
