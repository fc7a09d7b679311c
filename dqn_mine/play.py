"""`python -m dqn_mine.play`: record one episode of a policy to a GIF or MP4 (first-person view
and map).

    python -m dqn_mine.play --policy expert --task rooms --num-rooms 4 --out runs/play/expert.gif
    python -m dqn_mine.play --policy expert --episodes 200 --record demos/two-room

``--record DIR`` writes the episodes as demonstrations a run loads with ``--demos-from DIR``
(format: ``dqn_mine/demos.py``) instead of a video.

A policy is a callable ``policy(env, obs, info) -> action``; ``POLICIES`` maps a name to a factory
``factory(args) -> policy`` so that new kinds (a trained checkpoint) plug in by adding one entry.
"""

from __future__ import annotations

import argparse
import random
import sys
from pathlib import Path
from typing import Callable

import numpy as np

from dqn_mine.exitcodes import EXIT_BAD_INPUT
from dqn_mine.video import mp4_available, save_video

Policy = Callable[[object, np.ndarray, dict], int]


def expert_policy(args: argparse.Namespace) -> Policy:
    """The scripted planner with privileged state (dqn_mine/env/expert.py)."""
    return lambda env, obs, info: env.unwrapped.expert_action()


def random_policy(args: argparse.Namespace) -> Policy:
    """Uniformly random actions, seeded by --seed."""
    rng = random.Random(args.seed)
    return lambda env, obs, info: rng.randrange(env.action_space.n)


def bump_and_press_policy(args: argparse.Namespace) -> Policy:
    """The scripted walker that pre-fills the replay by default (``BumpAndPress``): straight
    ahead until the view stops changing, then action 4 and a turn away. Seeded by --seed."""
    from dqn_mine.agent.explore import BumpAndPress

    walker = BumpAndPress(1, np.random.default_rng(args.seed))
    last: list[np.ndarray | None] = [None]   # the frame before this one

    def act(env, obs, info) -> int:
        stuck = last[0] is not None and np.array_equal(last[0], obs)
        last[0] = obs
        return int(walker.act(np.zeros(1, np.int64), np.array([stuck]))[0])
    return act


def agent_policy(args: argparse.Namespace) -> Policy:
    """A trained network from --checkpoint (a run folder or a .pt file), near-greedy."""
    from dqn_mine.agent.policy import AgentPolicy
    from dqn_mine.machine import single_thread_inference

    single_thread_inference()
    return AgentPolicy.from_checkpoint(args.checkpoint, epsilon=args.epsilon, seed=args.seed,
                                       unstick=args.unstick, held=args.held)


def manual(args: argparse.Namespace) -> Callable:
    """A person at the keyboard (``dqn_mine.manual``): a window, or keys from --keys."""
    from dqn_mine.manual import manual_policy, stdin_keys

    if args.keys is None:
        return manual_policy()
    return manual_policy(stdin_keys(sys.stdin if args.keys == "-" else open(args.keys)))


POLICIES: dict[str, Callable[[argparse.Namespace], Policy]] = {
    "expert": expert_policy,
    "random": random_policy,
    "bump-and-press": bump_and_press_policy,
    "agent": agent_policy,
}

# Environment settings play takes from a checkpoint's config unless given on the command line.
ENV_DEFAULTS = {"task": "two-room", "room_size": 16.0, "placement": "fixed", "num_rooms": None,
                "max_steps": None, "room_colours": False, "camera_pitch": 0.0,
                "held_on_top": False}
CONFIG_KEYS = {"task": "task", "room_size": "room_size", "placement": "placement",
               "num_rooms": "num_rooms", "max_steps": "max_episode_steps"}


def fill_env_settings(args: argparse.Namespace) -> None:
    """Unset environment flags take the checkpoint's training settings, else the defaults."""
    trained = {}
    if args.checkpoint:
        from dqn_mine import checkpoint as ckpt
        from dqn_mine.env.mine import VIEWS

        config = ckpt.load(args.checkpoint)["config"]
        trained = {name: config[key] for name, key in CONFIG_KEYS.items()}
        trained.update(VIEWS[config["view"]])
    for name, default in ENV_DEFAULTS.items():
        if getattr(args, name) is None:
            setattr(args, name, trained.get(name, default))
    if args.task != "rooms":
        args.num_rooms = None


def make_env(args: argparse.Namespace):
    """The environment, built directly: ``gymnasium.make`` keeps ``max_episode_steps`` for its own
    TimeLimit wrapper and never passes it on, so the task's default limit would still cut a longer
    --max-steps short."""
    from dqn_mine.env import MineRescueEnv

    kwargs = dict(task=args.task, placement=args.placement, room_size=args.room_size,
                  render_mode="rgb_array", randomise_visuals=args.visual_randomisation)
    if args.num_rooms is not None:
        kwargs["num_rooms"] = args.num_rooms
    if args.phase is not None:
        kwargs["phase"] = args.phase
    kwargs.update(room_colours=args.room_colours, camera_pitch=args.camera_pitch,
                  held_on_top=args.held_on_top)
    if args.max_steps is not None:
        kwargs["max_episode_steps"] = args.max_steps
    return MineRescueEnv(**kwargs)


def record(env, policy: Policy, seed: int,
           progress: bool = True) -> tuple[list[np.ndarray], float, int]:
    """Run one episode; return its rendered frames, its return and its length."""
    from tqdm import tqdm

    obs, info = env.reset(seed=seed)
    frames = [env.render()]
    total, steps = 0.0, 0
    limit = env.unwrapped.max_episode_steps
    with tqdm(total=limit, desc="recording", unit="step", disable=not progress, leave=False) as bar:
        while True:
            obs, reward, terminated, truncated, info = env.step(policy(env, obs, info))
            frames.append(env.render())
            total += reward
            steps += 1
            bar.update(1)
            if terminated or truncated:
                break
    return frames, total, steps


def check_output_settings(args: argparse.Namespace, out: Path) -> None:
    """What would only fail after a whole episode was recorded: fail before it instead."""
    check_episode_settings(args)
    if not args.fps > 0:
        raise ValueError(f"--fps must be positive, got {args.fps}")
    check_video_path(out, "--out")


def check_record_settings(args: argparse.Namespace) -> None:
    check_episode_settings(args)
    if args.keys not in (None, "-") and not Path(args.keys).is_file():
        raise ValueError(f"--keys {args.keys}: no such file")
    if args.episodes < 1:
        raise ValueError(f"--episodes must be at least 1, got {args.episodes}")
    folder = Path(args.record)
    if folder.exists() and (not folder.is_dir() or any(folder.iterdir())):
        raise ValueError(f"--record {folder}: not an empty folder (demonstrations are never "
                         "mixed into an existing set)")


def check_video_path(out: Path, flag: str) -> None:
    if out.suffix.lower() not in (".gif", ".mp4") or out.is_dir():
        raise ValueError(f"{flag} must name a .gif or .mp4 file, got {out}")
    if out.suffix.lower() == ".mp4" and not mp4_available():
        raise ValueError(f"{flag} .mp4 needs imageio with ffmpeg (pip install -e .[video]); "
                         "a .gif needs nothing more")


PLAY_DEFAULTS = {"epsilon": 0.0, "unstick": False, "held": False}


def add_episode_arguments(ap: argparse.ArgumentParser, defaults: dict | None = None) -> None:
    """The flags that set up the episodes (``play`` and ``evaluate`` share them); ``defaults``
    describes in ``--help`` how an unset --epsilon, --unstick and --held get their value."""
    defaults = defaults or PLAY_DEFAULTS
    ap.add_argument("--epsilon", type=float, default=None,
                    help=f"agent's exploration rate (default: {defaults['epsilon']})")
    ap.add_argument("--unstick", action=argparse.BooleanOptionalAction, default=None,
                    help="agent: a random action after a step that left the frame unchanged "
                         f"(as training actors with --unstick act; default: {defaults['unstick']})")
    ap.add_argument("--held", action=argparse.BooleanOptionalAction, default=None,
                    help="agent: random actions (epsilon's and --unstick's) held as the run's "
                         f"ez training actors hold them (default: {defaults['held']})")
    ap.add_argument("--task", default=None, help="one-room, two-room, three-room or rooms "
                    "(default: the checkpoint's, else two-room, as for train)")
    ap.add_argument("--num-rooms", type=int, default=None,
                    help="rooms of the `rooms` task, 2..12 (default 4)")
    ap.add_argument("--room-size", type=float, default=None, help="side of each room in units")
    ap.add_argument("--placement", default=None, help="fixed or any-room (domain randomisation)")
    ap.add_argument("--phase", type=int, default=None,
                    help="curriculum phase: 1..6 of three-room")
    ap.add_argument("--visual-randomisation", action="store_true",
                    help="random light, wall colour and field of view")
    ap.add_argument("--room-colours", action=argparse.BooleanOptionalAction, default=None,
                    help="each room's floor in a colour of its own (default: the checkpoint's, "
                         "else off)")
    ap.add_argument("--camera-pitch", type=float, default=None,
                    help="degrees the camera looks down, 0..30 (default: the checkpoint's, else 0)")
    ap.add_argument("--held-on-top", action=argparse.BooleanOptionalAction, default=None,
                    help="the carried item drawn over the world (default: the checkpoint's, "
                         "else off)")
    ap.add_argument("--seed", type=int, default=0, help="episode seed (the first one)")
    ap.add_argument("--max-steps", type=int, default=None, help="step limit (default: the task's)")


def check_episode_settings(args: argparse.Namespace) -> None:
    if args.seed < 0:
        raise ValueError(f"--seed must be >= 0, got {args.seed}")
    if args.epsilon is not None and not 0.0 <= args.epsilon <= 1.0:
        raise ValueError(f"--epsilon must be in [0, 1], got {args.epsilon}")


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m dqn_mine.play",
                                 description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--policy", choices=sorted(POLICIES), default=None,
                    help="who acts (default: agent with --checkpoint, else expert)")
    ap.add_argument("--checkpoint", default=None,
                    help="trained agent: a run folder or checkpoint.pt (its task is the default)")
    add_episode_arguments(ap)
    ap.add_argument("--fps", type=float, default=15.0, help="frames per second of the video")
    ap.add_argument("--out", default=None, help="video to write, .gif or .mp4 (MP4: much smaller, "
                    "needs imageio-ffmpeg; default runs/play/<policy>.gif)")
    ap.add_argument("--record", default=None, metavar="DIR",
                    help="write the episodes as demonstrations to DIR (for train's --demos-from) "
                         "instead of a video")
    ap.add_argument("--manual", action="store_true",
                    help="play by hand and record it (needs --record): a window where a display "
                         "exists (w/s/a/d or arrows, space acts, q ends the episode)")
    ap.add_argument("--keys", default=None, metavar="FILE",
                    help="--manual: read the key presses as characters from FILE (- = standard "
                         "input; the default without a display) instead of a window")
    ap.add_argument("--episodes", type=int, default=1,
                    help="episodes to record with --record (seeds --seed, --seed + 1, ...)")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    return ap


def record_demos(env, policy: Policy, args: argparse.Namespace) -> int:
    """``--record``: ``--episodes`` episodes of ``policy`` written as demonstrations."""
    from tqdm import tqdm

    from dqn_mine import demos

    folder = Path(args.record)
    paths, delivered, steps = [], 0, 0
    act = policy if args.manual else lambda env, obs, info, t: policy(env, obs, info)
    for i in tqdm(range(args.episodes), desc="recording", unit="ep",
                  disable=args.quiet or args.manual):
        ep = demos.record_policy(env, act, args.seed + i)
        if ep.steps == 0:      # stopped before a step: nothing to keep
            continue
        paths.append(demos.save_episode(folder, len(paths), ep))
        delivered += ep.terminated
        steps += ep.steps
    if not paths:
        print("no episode was recorded", file=sys.stderr)
        return EXIT_BAD_INPUT
    demos.write_meta(folder, len(paths), steps, {key: getattr(args, key) for key in ENV_DEFAULTS})
    print(f"{args.policy} on {args.task}: {len(paths)} episodes (seeds from {args.seed}), "
          f"{delivered} delivered -> {folder}")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.manual and args.record is None:
        print("error: --manual records demonstrations: add --record DIR", file=sys.stderr)
        return EXIT_BAD_INPUT
    args.policy = "manual" if args.manual else \
        args.policy or ("agent" if args.checkpoint else "expert")
    if args.policy == "agent" and not args.checkpoint:
        print("error: --policy agent needs --checkpoint RUN_DIR", file=sys.stderr)
        return EXIT_BAD_INPUT
    out = Path(args.out or f"runs/play/{args.policy}.gif")
    try:
        if args.record is None:
            check_output_settings(args, out)
        else:
            check_record_settings(args)
        fill_env_settings(args)
        for name, value in PLAY_DEFAULTS.items():
            if getattr(args, name) is None:
                setattr(args, name, value)
        env = make_env(args)
        policy = manual(args) if args.manual else POLICIES[args.policy](args)
    except ValueError as exc:  # bad settings, or CheckpointError (a ValueError)
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.record is not None:
        return record_demos(env, policy, args)
    frames, total, steps = record(env, policy, args.seed, progress=not args.quiet)
    env.close()
    save_video(frames, out, args.fps)
    print(f"{args.policy} on {args.task} (seed {args.seed}): "
          f"return {total:.1f} in {steps} steps -> {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
