"""The acting core: what the network is fed, and that AgentPolicy feeds it what the actors did."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from dqn_mine.agent.acting import ActingCore
from dqn_mine.agent.explore import Explorer
from dqn_mine.agent.network import DuelingQNetwork
from dqn_mine.agent.policy import AgentPolicy
from dqn_mine.env import MineRescueEnv
from dqn_mine.env.expert import solve
from dqn_mine.env.interface import FRAME_SHAPE
from dqn_mine.system.control import Episode
from dqn_mine.system.episodes import EpisodeStats


def frame(value: int) -> np.ndarray:
    return np.full(FRAME_SHAPE, value, dtype=np.uint8)


def core_of(num_envs=2, frame_stack=3, history_len=4, unstick=False, cycle=1) -> ActingCore:
    torch.manual_seed(0)
    net = DuelingQNetwork(frame_stack=frame_stack, history_len=history_len).eval()
    explorer = Explorer(0.0, num_envs, np.random.default_rng(0), unstick=unstick)
    return ActingCore(net, explorer, num_envs, frame_stack, history_len, unstick_cycle=cycle)


def test_frames_and_actions_are_kept_oldest_first_and_reset_per_episode():
    core = core_of()
    core.begin(1, frame(7), carrying=False)
    assert (core.stacks[1, :6] == 0).all() and (core.stacks[1, 6:] == 7).all()
    core.observe(1, 2, frame(8), carrying=True)
    core.observe(1, 4, frame(9), carrying=True)
    assert [int(core.stacks[1, 3 * k, 0, 0]) for k in range(3)] == [7, 8, 9]
    assert core.histories[1].tolist() == [-1, -1, 2, 4] and core.carrying[1] == 1.0
    assert (core.stacks[0] == 0).all() and core.histories[0].tolist() == [-1] * 4
    core.begin(1, frame(3), carrying=False)
    assert core.histories[1].tolist() == [-1] * 4 and core.carrying[1] == 0.0
    assert (core.stacks[1, :6] == 0).all()


def test_an_unchanged_frame_counts_as_stuck_only_when_unsticking():
    plain, unstick = core_of(unstick=False), core_of(unstick=True)
    for core in (plain, unstick):
        core.begin(0, frame(5), carrying=False)
        core.observe(0, 5, frame(5), carrying=False)
    assert not plain.stuck[0] and unstick.stuck[0]
    unstick.observe(0, 0, frame(6), carrying=False)
    assert not unstick.stuck[0]


@pytest.mark.parametrize("cycle", [1, 2, 3])
def test_a_frame_back_within_the_cycle_counts_as_stuck(cycle):
    """Frames 5, 6, 5, 7, 8, 9, 7: the second 5 closes a loop of two steps, the second 7 one of
    three; a loop counts when it is no longer than the cycle. A new episode forgets the old."""
    core = core_of(frame_stack=1, unstick=True, cycle=cycle)
    core.begin(0, frame(5), carrying=False)
    stuck = []
    for value in (6, 5, 7, 8, 9, 7):
        core.observe(0, 0, frame(value), carrying=False)
        stuck.append(bool(core.stuck[0]))
    assert stuck == [False, cycle >= 2, False, False, False, cycle >= 3]
    core.begin(0, frame(9), carrying=False)
    core.observe(0, 0, frame(7), carrying=False)
    assert not core.stuck[0]
    core.observe(0, 0, frame(7), carrying=False)
    assert core.stuck[0]


def where_the_expert_puts_a_boulder_down(env, seed: int):
    """(obs, info) of the state where the expert, playing its solution of ``seed``, is about
    to put a held boulder down."""
    plan = solve(env, seed, env.max_episode_steps)
    obs, info = env.reset(seed=seed)
    for action in plan:
        if info["carrying"] and not info["carrying_kit"] and action == 4:
            return obs, info
        obs, _, _, _, info = env.step(action)
    pytest.fail("the expert's solution never puts a boulder down")


def test_putting_a_held_boulder_down_and_up_again_is_a_two_step_loop():
    """In the real mine, action 4 pressed again and again while holding a boulder puts it down
    and takes it up: the frames alternate, which a cycle of 2 catches and a cycle of 1 misses.
    So does a left turn undone by a right one."""
    env = MineRescueEnv(task="three-room")
    obs, info = where_the_expert_puts_a_boulder_down(env, seed=3)
    cores = {k: core_of(num_envs=1, frame_stack=1, unstick=True, cycle=k) for k in (1, 2)}
    for core in cores.values():
        core.begin(0, obs, info["carrying"])
    stuck = {1: [], 2: []}
    for action in (4, 4, 4, 4, 0, 2, 3):   # down, up, down, up; a step; left, right
        obs, _, _, _, info = env.step(action)
        for k, core in cores.items():
            core.observe(0, action, obs, info["carrying"])
            stuck[k].append(bool(core.stuck[0]))
    env.close()
    assert stuck == {1: [False] * 7, 2: [False, True, True, True, False, False, True]}


def test_greedy_actions_come_from_one_batched_forward_pass():
    core = core_of(num_envs=3)
    for j in range(3):
        core.begin(j, frame(40 * j), carrying=j == 1)
    actions, q = core.act()
    assert q.shape == (3, 6) and q.dtype == np.float32
    assert actions.tolist() == q.argmax(axis=1).tolist()          # epsilon 0
    np.testing.assert_allclose(core.q_values(slice(1, 2))[0], q[1], rtol=1e-5, atol=1e-6)


def test_agent_policy_feeds_the_network_what_a_training_actor_feeds_it():
    """Step one environment with a policy and a second with an actor's core, in lockstep: the
    same inputs, so the same greedy actions all episode long."""
    torch.manual_seed(1)
    net = DuelingQNetwork(frame_stack=2, history_len=5).eval()
    policy = AgentPolicy(net, frame_stack=2, history_len=5)
    core = ActingCore(net, Explorer(0.0, 1, np.random.default_rng(0)), 1, 2, 5)
    envs = [MineRescueEnv(task="one-room", room_size=8.0, max_episode_steps=25)
            for _ in range(2)]
    (obs, info), (obs2, info2) = (env.reset(seed=3) for env in envs)
    policy.reset()
    core.begin(0, obs2, info2["carrying"])
    for _ in range(25):
        action = policy.predict(obs, info)
        actions, _ = core.act()
        assert action == int(actions[0])
        np.testing.assert_array_equal(policy.core.stacks, core.stacks)
        np.testing.assert_array_equal(policy.core.histories, core.histories)
        np.testing.assert_array_equal(policy.core.carrying, core.carrying)
        obs, _, term, trunc, info = envs[0].step(action)
        obs2, _, _, _, info2 = envs[1].step(action)
        core.observe(0, action, obs2, info2["carrying"])
        if term or trunc:
            break
    for env in envs:
        env.close()


def test_agent_policy_unsticks_only_when_asked(noop_network):
    """Fed the same frame again (a no-op changes nothing), the unsticking policy acts randomly
    from the second step on; the plain one repeats its greedy no-op."""
    frame = np.full(FRAME_SHAPE, 7, np.uint8)
    actions = {}
    for unstick in (False, True):
        policy = AgentPolicy(noop_network(history_len=3), frame_stack=1, history_len=3, seed=4,
                             unstick=unstick)
        policy.reset()
        actions[unstick] = [policy.predict(frame) for _ in range(60)]
    assert actions[False] == [5] * 60
    assert actions[True][0] == 5                       # nothing seen before: not stuck
    random_part = np.array(actions[True][1:])
    assert (random_part != 5).mean() > 0.6             # uniform: 5 of 6 actions are not the no-op
    assert len(set(random_part.tolist())) == 6


def test_episode_stats_keep_training_and_evaluation_apart():
    from dqn_mine.config import parse_args

    stats = EpisodeStats(parse_args(["--eval-episodes", "2"]), episodes=10)
    assert stats.add(Episode(0, 1.0, 30, 5, False))
    assert not stats.add(Episode(1, 0.0, 50, 0, True))
    assert stats.episodes == 11 and stats.returns.mean == 1.0 and stats.lengths.mean == 30
    assert stats.eval_returns.mean == 0.0 and stats.eval_lengths.mean == 50
    assert len(stats.low_eps_returns) == 0       # an episode of unknown rate is not low
    stats.add(Episode(0, 0.0, 1000, 5, False, epsilon=0.4))
    stats.add(Episode(0, 0.0, 1000, 5, False, epsilon=0.01))
    stats.add(Episode(0, 1.0, 900, 5, False, epsilon=0.001))
    assert stats.returns.mean == pytest.approx(0.5) and stats.low_eps_returns.mean == 0.5
