"""Environment settings the environment tests share: every task and placement at full size."""

TASK_CONFIGS = [
    dict(task="one-room"),
    dict(task="two-room"),
    dict(task="three-room"),
    dict(task="rooms", num_rooms=2),
    dict(task="rooms", num_rooms=4),
    dict(task="two-room", placement="any-room"),
    dict(task="three-room", placement="any-room"),
    dict(task="rooms", num_rooms=4, placement="any-room"),
]


def ids(configs: list[dict]) -> list[str]:
    """Readable test ids: the settings' values joined."""
    return ["-".join(str(v) for v in c.values()) for c in configs]
