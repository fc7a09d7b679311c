"""The first-person 3D mine rescue environment, registered as ``dqn_mine/MineRescue-v0``.

Importing this package does not create a GL context; the first render of a process does.
"""

ENV_ID = "dqn_mine/MineRescue-v0"


def register_envs() -> None:
    """Register ``dqn_mine/MineRescue-v0`` with gymnasium (idempotent).

    No ``max_episode_steps`` here: the environment truncates itself at its task's limit, so the
    made environment behaves like the raw class. Note that ``gymnasium.make`` keeps a
    ``max_episode_steps`` keyword for its own TimeLimit wrapper instead of passing it on, so it can
    only shorten the task's limit; to lengthen it, construct ``MineRescueEnv(max_episode_steps=N)``.
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
