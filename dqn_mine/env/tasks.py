"""The rescue tasks: where the agent, the kit, the miner and the boulders start.

| task         | rooms       | start (placement="fixed")                | doorways | steps |
|--------------|-------------|------------------------------------------|----------|-------|
| `one-room`   | 1           | agent, kit, miner anywhere in the room   | -        | 1000  |
| `two-room`   | 2           | agent in room 0; kit and miner in room 1 | blocked  | 1000  |
| `three-room` | 3 (a chain) | agent and miner in room 0; kit in room 2 | blocked  | 2000  |
| `rooms`      | N >= 2      | agent, kit, miner each in a random room  | blocked  | 2000  |

``placement="any-room"`` (domain randomisation) puts the agent, the kit and the miner each in a
uniformly random room; the family still contains the fixed task. For ``rooms`` both placements
are the same. Rooms are numbered in the order they were placed (the chain order for three-room).

Curriculum phases of ``three-room`` (1 is the full task; the study trained 6 first; the other
tasks have none):

| phase | start                                                              |
|-------|--------------------------------------------------------------------|
| 1     | the full task                                                      |
| 2     | agent in room 1; the boulder between rooms 0 and 1 moved aside     |
| 3     | agent in room 2; both boulders moved aside                         |
| 4     | agent in room 2 carrying the kit; both boulders moved aside        |
| 5     | agent in room 1 carrying the kit; both boulders moved aside        |
| 6     | agent in room 0 (with the miner) carrying the kit; both aside      |
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import Callable

from dqn_mine.env.entities import KIT, MINER, Entity
from dqn_mine.env.mine import MIN_ROOM_SIZE, MineEnv

# The expert solves every episode within the 2,000-step limit up to 12 rooms (measured: at most
# 1,363 steps over 40 seeds each of 6-12 rooms); at 16 rooms some episodes need more.
MAX_ROOMS = 12
PLACEMENTS = ("fixed", "any-room")


@dataclass(frozen=True)
class Phase:
    agent_room: int
    boulders_aside: int   # how many doorways (in chain order) are already cleared
    carrying_kit: bool


PHASES = {
    1: Phase(0, 0, False),
    2: Phase(1, 1, False),
    3: Phase(2, 2, False),
    4: Phase(2, 2, True),
    5: Phase(1, 2, True),
    6: Phase(0, 2, True),
}
FULL_TASK = PHASES[1]        # phase 1 of every table: no boulder moved, no item in hand
TASK_PHASES = {"three-room": PHASES}


def phase_table(task: str) -> dict[int, Phase]:
    """The curriculum phases of ``task`` (1 = the full task)."""
    if task not in TASK_PHASES:
        raise ValueError(f"curriculum phases exist only for task 'three-room', not {task!r}")
    return TASK_PHASES[task]


def _one_room(env: MineRescueEnv) -> None:
    env.build_layout(1, chain=False)
    env.place(MINER, 0)
    env.place(KIT, 0)
    env.place_agent(0)


def _two_room(env: MineRescueEnv) -> None:
    env.build_layout(2, chain=False)
    _populate(env, env.block_doorways(), kit_room=1, miner_room=1)


def _three_room(env: MineRescueEnv) -> None:
    env.build_layout(3, chain=True)
    _populate(env, env.block_doorways(), kit_room=2, miner_room=0)


def _populate(env: MineRescueEnv, boulders, kit_room: int, miner_room: int) -> None:
    """Place miner, kit and agent: the full task (agent in room 0), or a curriculum phase."""
    if env.phase is None or env.phase == 1:
        agent, kit, miner = env.start_rooms(fixed=(0, kit_room, miner_room))
        phase = FULL_TASK
    else:
        phase = phase_table(env.task)[env.phase]
        agent, kit, miner = phase.agent_room, kit_room, miner_room
        for boulder, door in list(zip(boulders, env.layout.doors))[:phase.boulders_aside]:
            env.move_aside(boulder, door)
    env.place(MINER, miner)
    if phase.carrying_kit:
        env.carrying = env.add(Entity(KIT))
    else:
        env.place(KIT, kit)
    env.place_agent(agent)


def _rooms(env: MineRescueEnv) -> None:
    n = env.num_rooms
    env.build_layout(n, chain=False)
    env.block_doorways()
    agent, kit, miner = env.random_rooms(3)
    env.place(MINER, miner)
    env.place(KIT, kit)
    env.place_agent(agent)


@dataclass(frozen=True)
class Task:
    name: str
    rooms: int | None          # None: set by num_rooms
    step_limit: int
    generate: Callable[[MineRescueEnv], None]


TASKS = {t.name: t for t in [
    Task("one-room", 1, 1000, _one_room),
    Task("two-room", 2, 1000, _two_room),
    Task("three-room", 3, 2000, _three_room),
    Task("rooms", None, 2000, _rooms),
]}
DEFAULT_NUM_ROOMS = 4


class MineRescueEnv(MineEnv):
    """Rescue an injured miner: fetch the first-aid kit, clear boulders, deliver the kit.

    Observation: first-person RGB, uint8 FRAME_SHAPE (3, height 44, width 76).
    Actions: 0 forward 0.5, 1 backward 0.5, 2 turn right 9 deg, 3 turn left 9 deg,
        4 pick up / drop / exchange / deliver, 5 no-op.
    Reward: 1.0 when the kit is handed to the miner (terminated), else 0.0.
    Truncation: after ``max_episode_steps`` steps.
    Info: ``carrying``, ``carrying_kit``; at reset also ``agent_room``, ``kit_room``,
        ``miner_room``, ``num_rooms``.

    Args:
        task: "one-room", "two-room", "three-room" or "rooms" (see dqn_mine/env/tasks.py).
        num_rooms: rooms of the ``rooms`` task (>= 2, default 4); other tasks accept only their own
            count.
        room_size: side of each square room in units (>= 8).
        max_episode_steps: step limit; None means the task's default.
        placement: "fixed" or "any-room" (domain randomisation of the start rooms).
        phase: curriculum phase 1..6 of ``three-room`` (1 = the full task), or None; the other
            tasks have no phases (``two-room`` still accepts 1, its full task).
        render_mode: None or "rgb_array" (first-person view and map side by side).
        randomise_visuals: draw the light level, the wall colour and the field of view anew each
            episode (visual domain randomisation; the layout of a seed does not change).
        room_colours: each room's floor in a colour of its own, by room index (the rooms are
            otherwise alike, and the view through a doorway then shows which room lies beyond).
        camera_pitch: degrees the camera looks down, 0..30 (0: level, MiniWorld's camera; at 15
            an item within action 4's reach stays at least partly in view).
        held_on_top: the carried item drawn over the world, so that a near wall or a faced
            item no longer hides it (see ``HELD_TOP_ANGLE`` in ``dqn_mine/env/mine.py``).
    """

    def __init__(self, task: str = "two-room", num_rooms: int | None = None,
                 room_size: float = 16.0, max_episode_steps: int | None = None,
                 placement: str = "fixed", phase: int | None = None,
                 render_mode: str | None = None, randomise_visuals: bool = False,
                 room_colours: bool = False,
                 camera_pitch: float = 0.0, held_on_top: bool = False):
        if task not in TASKS:
            raise ValueError(f"unknown task {task!r}; choose one of {', '.join(TASKS)}")
        spec = TASKS[task]
        self.task = task
        self.num_rooms = _check_rooms(spec, num_rooms)
        if (not isinstance(room_size, numbers.Real) or isinstance(room_size, bool)
                or not 0 < room_size < math.inf):
            raise ValueError(f"room_size must be a positive finite number, got {room_size!r}")
        if room_size < MIN_ROOM_SIZE:
            raise ValueError(f"room_size must be at least {MIN_ROOM_SIZE:g} to hold the entities, "
                             f"got {room_size!r}")
        if max_episode_steps is None:
            max_episode_steps = spec.step_limit
        if not _is_int(max_episode_steps) or max_episode_steps <= 0:
            raise ValueError(
                f"max_episode_steps must be a positive integer, got {max_episode_steps!r}")
        if placement not in PLACEMENTS:
            raise ValueError(f"placement must be one of {', '.join(PLACEMENTS)}, got {placement!r}")
        self.placement = placement
        self.phase = _check_phase(task, placement, phase)
        super().__init__(max_episode_steps, room_size, render_mode, randomise_visuals,
                         room_colours, camera_pitch, held_on_top)

    def _generate(self) -> None:
        TASKS[self.task].generate(self)

    def start_rooms(self, fixed: tuple[int, int, int]) -> tuple[int, int, int]:
        """(agent, kit, miner) rooms: the task's own, or random ones under domain randomisation."""
        if self.placement == "fixed":
            return fixed
        return self.random_rooms(3)


def _is_int(value) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def _check_rooms(spec: Task, num_rooms) -> int:
    if spec.rooms is not None:
        if num_rooms is not None and num_rooms != spec.rooms:
            raise ValueError(f"task {spec.name!r} has exactly {spec.rooms} room(s), "
                             f"got num_rooms={num_rooms!r}")
        return spec.rooms
    if num_rooms is None:
        return DEFAULT_NUM_ROOMS
    if not _is_int(num_rooms) or not 2 <= num_rooms <= MAX_ROOMS:
        raise ValueError(f"task {spec.name!r} needs an integer num_rooms in 2..{MAX_ROOMS}, "
                         f"got {num_rooms!r}")
    return int(num_rooms)


def _check_phase(task: str, placement: str, phase) -> int | None:
    if phase is None:
        return None
    # two-room's phase table is gone (the backward curriculum replaced it); its phase 1, the full
    # task, is still accepted as before
    if not (task == "two-room" and _is_int(phase) and phase == 1):
        phases = phase_table(task)   # raises for a task without phases
        if not _is_int(phase) or phase not in phases:
            raise ValueError(f"phase must be an integer in 1..{len(phases)} or None for "
                             f"{task!r}, got {phase!r}")
    if placement != "fixed":
        raise ValueError("curriculum phases need placement='fixed'")
    return int(phase)
