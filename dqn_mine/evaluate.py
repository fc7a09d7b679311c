"""`python -m dqn_mine.evaluate RUN_DIR_OR_CHECKPOINT --episodes N`: a trained agent's score.

Plays N episodes (seeds S, S+1, ...) greedily, or with ``--epsilon``, on the task the checkpoint
was trained on unless ``--task`` and the other environment flags say otherwise; prints the mean
and spread of the return, the success rate and the mean length, and writes ``eval.json`` next to
the checkpoint (``--out`` elsewhere). ``--video PATH`` also records one of the scored episodes
(GIF, or MP4 with imageio-ffmpeg): the first, or with ``--video-of delivered`` the first that
delivered (an agent that succeeds now and then on a long task is worth seeing succeed).
``outcomes`` counts how the episodes ended: delivered, still holding the kit or a boulder, the
kit taken and dropped, the kit never taken though its room was entered, the kit's room never
entered.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from dqn_mine.env.entities import KIT
from dqn_mine.exitcodes import EXIT_BAD_INPUT
from dqn_mine.play import (
    add_episode_arguments,
    check_episode_settings,
    check_video_path,
    fill_env_settings,
    make_env,
)
from dqn_mine.system.specs import EVAL_EPSILON
from dqn_mine.video import save_video


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m dqn_mine.evaluate",
                                 description=__doc__.split("\n\n")[0])
    ap.add_argument("checkpoint", help="run folder or checkpoint.pt")
    ap.add_argument("--episodes", type=int, default=20, help="episodes to play")
    add_episode_arguments(ap, {name: f"{value}, as the run's evaluation actor"
                               for name, value in EVAL_DEFAULTS.items()})
    ap.add_argument("--video", default=None, help="video of a scored episode (.gif or .mp4)")
    ap.add_argument("--video-of", choices=VIDEO_OF, default="first",
                    help="which episode --video records: the first, or the first delivered "
                         "(none delivered: no video)")
    ap.add_argument("--video-stride", type=int, default=1,
                    help="keep every Nth frame of the video, and the last (a 2,000-step "
                         "episode is a GIF of ~25 MB at 1)")
    ap.add_argument("--out", default=None, help="eval.json path (default: next to the checkpoint)")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    return ap


VIDEO_OF = ("first", "delivered")
# Unset flags: as the run's evaluation actor plays (near-greedy, no held or unstick actions).
EVAL_DEFAULTS = {"epsilon": EVAL_EPSILON, "unstick": False, "held": False}

# How an episode ended, for eval.json's "outcomes": what failed, not only that it did.
OUTCOMES = ("delivered", "holding the kit", "holding a boulder", "kit dropped",
            "kit never taken", "kit's room never entered", "start room never left")


def play_episode(env, agent, seed: int, frames: list | None = None) -> tuple[float, int, str]:
    """Return, length and outcome (one of OUTCOMES) of one episode; its rendered frames are
    appended to ``frames`` when given."""
    obs, info = env.reset(seed=seed)
    agent.reset()
    mine, kit_room = env.unwrapped, info["kit_room"]
    total, steps, had_kit = 0.0, 0, info["carrying_kit"]
    start_room = info["agent_room"]
    entered, left = start_room == kit_room, False
    while True:
        if frames is not None:
            frames.append(env.render())
        obs, reward, terminated, truncated, info = env.step(agent.predict(obs, info))
        total += reward
        steps += 1
        had_kit = had_kit or info["carrying_kit"]
        entered = entered or mine.agent_room == kit_room
        left = left or mine.agent_room != start_room
        if terminated or truncated:
            if frames is not None:
                frames.append(env.render())
            return total, steps, _outcome(mine, terminated, had_kit, entered, left)


def _outcome(env, terminated: bool, had_kit: bool, entered_kit_room: bool = True,
             left_start_room: bool = True) -> str:
    """``entered_kit_room``: the agent was in the kit's starting room at some step (in
    three-room, an agent that never took the kit mostly went the wrong way, into the miner's
    room, rather than missing a kit it saw); ``left_start_room``: it was ever outside the room
    it started in (an agent lost in its first room is a failure of its own, apart from one
    that went the wrong way)."""
    if terminated:
        return "delivered"
    if env.carrying is not None:
        return "holding the kit" if env.carrying.kind == KIT else "holding a boulder"
    if had_kit:
        return "kit dropped"
    if entered_kit_room:
        return "kit never taken"
    return "kit's room never entered" if left_start_room else "start room never left"


def evaluate(env, agent, episodes: int, seed: int, progress: bool = True,
             video_of: str | None = None) -> tuple[dict, list]:
    """Scores of ``episodes`` episodes with seeds ``seed``, ``seed + 1``, ..., and the frames of
    the episode ``video_of`` names (see VIDEO_OF; none: no frames). Filming renders only until
    that episode is found; the scores are the same with or without it."""
    from tqdm import tqdm

    returns, lengths, outcomes = [], [], dict.fromkeys(OUTCOMES, 0)
    filmed, filmed_seed = [], None
    for i in tqdm(range(episodes), desc="evaluating", unit="episode", disable=not progress):
        frames = [] if video_of and filmed_seed is None else None
        total, steps, outcome = play_episode(env, agent, seed + i, frames)
        if frames is not None and (video_of == "first" or outcome == "delivered"):
            filmed, filmed_seed = frames, seed + i
        returns.append(total)
        lengths.append(steps)
        outcomes[outcome] += 1
    returns = np.asarray(returns)
    return {"episodes": episodes, "success_rate": float(np.mean(returns > 0)),
            "mean_return": float(returns.mean()), "std_return": float(returns.std()),
            "mean_length": float(np.mean(lengths)), "seed": seed, "outcomes": outcomes,
            "video_seed": filmed_seed}, filmed


def every_nth(frames: list, n: int) -> list:
    """Frames 0, n, 2n, ... and the last one (the delivery) in any case."""
    kept = frames[::n]
    if (len(frames) - 1) % n:
        kept.append(frames[-1])
    return kept


def check_settings(args: argparse.Namespace) -> None:
    if args.episodes < 1:
        raise ValueError(f"--episodes must be at least 1, got {args.episodes}")
    check_episode_settings(args)
    if args.video:
        check_video_path(Path(args.video), "--video")
    if args.video_stride < 1:
        raise ValueError(f"--video-stride must be at least 1, got {args.video_stride}")


def fill_eval_settings(args: argparse.Namespace) -> None:
    """Unset flags: what the run's evaluation actor plays, so that a first evaluation scores the
    real thing: the full target task (its room count, fixed placement; no curriculum start),
    near-greedily."""
    from dqn_mine import checkpoint as ckpt

    trained = ckpt.load(args.checkpoint)["config"]
    for name, value in EVAL_DEFAULTS.items():
        if getattr(args, name) is None:
            setattr(args, name, value)
    if args.placement is None:
        args.placement = "fixed"
    if args.num_rooms is None and (args.task or trained["task"]) == "rooms":
        scheduled = trained.get("curriculum") == "schedule"
        last = trained["rooms_schedule"][-1] if scheduled else None
        args.num_rooms = trained.get("eval_num_rooms") or last


def output_path(args: argparse.Namespace) -> Path:
    if args.out:
        return Path(args.out)
    ckpt = Path(args.checkpoint)
    return (ckpt if ckpt.is_dir() else ckpt.parent) / "eval.json"


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        check_settings(args)
        from dqn_mine import load_agent
        from dqn_mine.machine import single_thread_inference

        single_thread_inference()
        fill_eval_settings(args)
        agent = load_agent(args.checkpoint, epsilon=args.epsilon, seed=args.seed,
                           unstick=args.unstick, held=args.held)
        fill_env_settings(args)
        env = make_env(args)
    except ValueError as exc:  # bad settings, or CheckpointError (a ValueError)
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    try:
        scores, frames = evaluate(env, agent, args.episodes, args.seed, progress=not args.quiet,
                                  video_of=args.video_of if args.video else None)
        if frames:
            save_video(every_nth(frames, args.video_stride), Path(args.video), 15.0)
    finally:
        env.close()
    scores.update(task=args.task, placement=args.placement, num_rooms=args.num_rooms,
                  epsilon=args.epsilon, unstick=args.unstick, held=args.held,
                  checkpoint=str(args.checkpoint))
    out = output_path(args)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(scores, indent=1))
    print(f"{args.task}, {scores['episodes']} episodes (seeds {args.seed}..."
          f"{args.seed + args.episodes - 1}): return {scores['mean_return']:.3f} +- "
          f"{scores['std_return']:.3f}, success {scores['success_rate']:.0%}, "
          f"mean length {scores['mean_length']:.0f} -> {out}")
    print("  ended: " + ", ".join(f"{k} {v}" for k, v in scores["outcomes"].items() if v))
    if args.video:
        print(f"  video: episode seed {scores['video_seed']} -> {args.video}" if frames else
              f"  video: no episode delivered, none written (--video-of {args.video_of})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
