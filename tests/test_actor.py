"""An actor in this process: it acts with the broadcast weights in the precision it was given."""

import contextlib
import dataclasses

import numpy as np
import torch

from dqn_mine.agent.learning import epsilon_for_actor
from dqn_mine.agent.network import DuelingQNetwork
from dqn_mine.config import PRESETS, Config
from dqn_mine.replay import ReplayStorage
from dqn_mine.shared import SharedBlocks
from dqn_mine.system.actor import Actor
from dqn_mine.system.control import Control
from dqn_mine.system.evaluator import EvalActor
from dqn_mine.system.layout import replay_layout, run_block_specs
from dqn_mine.system.specs import actor_specs
from dqn_mine.system.weights import WeightBroadcast


@contextlib.contextmanager
def _run_blocks(cfg, net, phase=0):
    """The run's shared blocks with ``net``'s weights published and ``phase`` set."""
    with SharedBlocks.create(run_block_specs(cfg, net)) as blocks:
        blocks["ctl_phase"][0] = phase
        weights = WeightBroadcast(blocks)
        weights.publish(net)
        yield blocks, weights


@contextlib.contextmanager
def in_process_actor(cfg, net, spec=None, phase=0):
    """An actor of ``cfg`` in this process, acting on ``net``'s published weights; ``phase``:
    the curriculum phase in the shared control block when it starts."""
    with _run_blocks(cfg, net, phase) as (blocks, weights):
        actor = Actor(cfg, spec or actor_specs(cfg)[0],
                      ReplayStorage(replay_layout(cfg), blocks), Control(blocks), weights)
        try:
            yield actor
        finally:
            actor.close()


def test_bfloat16_actor_acts_on_the_published_weights():
    cfg = dataclasses.replace(Config(**PRESETS["smoke"], preset="smoke"), actors=1,
                              envs_per_actor=2, replay_capacity=4096, eval_every=0,
                              precision="bfloat16").validate()
    torch.manual_seed(0)
    learner_net = DuelingQNetwork(frame_stack=cfg.frame_stack, history_len=cfg.history_len)
    with in_process_actor(cfg, learner_net) as actor:
        assert actor.version == 1
        # heavy layers in bfloat16, output layers float32 (action gaps keep float32 precision)
        assert {p.dtype for p in actor.net.conv.parameters()} == {torch.bfloat16}
        assert {p.dtype for p in actor.net.advantage[2].parameters()} == {torch.float32}
        for _ in range(30):
            actor.step()
        core = actor.core
        q = core.q_values()                                                    # [E, A]
        with torch.inference_mode():
            expected = learner_net(torch.from_numpy(core.stacks),
                                   torch.from_numpy(core.histories),
                                   torch.from_numpy(core.carrying)).numpy()
        assert q.dtype == expected.dtype and q.shape == (2, 6)
        assert abs(q - expected).max() < 0.02 * abs(expected).max()
        assert (q.argmax(1) == expected.argmax(1)).all()
        assert actor.steps == 60
        for writer in actor.writers:                   # publish what close() would
            writer.flush()
        assert actor.writers[0].storage.total_written() == 60


def test_ez_actor_holds_random_motions_with_one_rate_per_env():
    cfg = dataclasses.replace(Config(**PRESETS["smoke"], preset="smoke"), actors=2,
                              envs_per_actor=3, replay_capacity=4096, eval_every=0,
                              exploration="ez").validate()
    specs = actor_specs(cfg)
    # the Ape-X schedule runs over all 6 environments, not over the 2 processes
    rates = [eps for spec in specs for eps in spec.epsilon]
    assert rates == [epsilon_for_actor(k, 6) for k in range(6)]
    net = DuelingQNetwork(frame_stack=cfg.frame_stack, history_len=cfg.history_len)
    with in_process_actor(cfg, net, specs[0]) as actor:
        explorer = actor.core.explorer
        assert explorer.durations
        assert list(explorer.epsilon) == rates[:3]
        held = 0
        for _ in range(200):
            actor.step()
            held += int((explorer.left > 0).sum())
        assert held > 0, "env 0 (epsilon 0.4) must start runs that last several steps"
        assert actor.steps == 600


def _actions_taken(cfg, steps: int, net):
    with in_process_actor(cfg, net) as actor:
        actor.core.explorer.epsilon[:] = 0.0
        taken, stuck = [], []
        for _ in range(steps):
            actor.step()
            taken.append(actor.core.histories[:, -1].copy())    # each env's last action
            stuck.append(actor.core.stuck.copy())
        return np.array(taken), np.array(stuck)            # [T, E]


def test_unstick_turns_a_stuck_greedy_policy_random_only_while_stuck(noop_network):
    cfg = dataclasses.replace(Config(**PRESETS["smoke"], preset="smoke"), actors=1,
                              envs_per_actor=2, replay_capacity=4096, eval_every=0)
    net = noop_network(cfg.frame_stack, cfg.history_len)
    taken, stuck = _actions_taken(cfg.validate(), 40, net)
    assert (taken == 5).all(), "without unstick a no-op policy never moves"
    assert not stuck.any(), "and the actor does not compare frames it has no use for"
    taken, stuck = _actions_taken(dataclasses.replace(cfg, unstick=1).validate(), 40, net)
    # a no-op leaves the frame as it was, so the step after it is random; a random step that
    # moved or turned gives the greedy no-op back
    assert (taken[1:][stuck[:-1]] != 5).mean() > 0.6     # uniform: 5 of 6 are not the no-op
    assert (taken[1:][~stuck[:-1]] == 5).all()
    assert 0.2 < stuck.mean() < 0.9


def test_evaluation_actor_plays_near_greedily_whatever_the_training_actors_do():
    """Training actors with ez's held actions and --unstick 2; the evaluation actor plays
    epsilon 0.01 with neither, while a training actor of the same run has both."""
    cfg = dataclasses.replace(Config(**PRESETS["cpu-rooms"], preset="cpu-rooms"), actors=1,
                              envs_per_actor=1, replay_capacity=4096, eval_every=1000,
                              eval_episodes=1, curriculum="none").validate()
    net = DuelingQNetwork(frame_stack=cfg.frame_stack, history_len=cfg.history_len)
    with _run_blocks(cfg, net) as (blocks, weights):
        actor = EvalActor(cfg, actor_specs(cfg)[-1], Control(blocks), weights)
        try:
            explorer = actor.core.explorer
            assert not explorer.unstick and not explorer.durations
            assert list(explorer.epsilon) == [0.01]
        finally:
            actor.close()
    with in_process_actor(cfg, net) as trainer:
        explorer = trainer.core.explorer
        assert explorer.unstick and explorer.durations and trainer.core.recent.shape[1] == 2


def test_actor_starts_episodes_in_the_shared_phase_and_records_them():
    """Episodes start in the phase the shared state names, and end at the step limit; the
    environment really stops there, and the episode record says so."""
    cfg = dataclasses.replace(Config(**PRESETS["cpu"], preset="cpu"), actors=1,
                              envs_per_actor=2, replay_capacity=4096, eval_every=0,
                              task="three-room", curriculum="adaptive", max_episode_steps=25,
                              curriculum_review=0.0).validate()
    net = DuelingQNetwork(frame_stack=cfg.frame_stack, history_len=cfg.history_len)
    with in_process_actor(cfg, net, phase=6) as actor:
        assert [env.max_episode_steps for env in actor.envs] == [25, 25]
        assert [env.phase for env in actor.envs] == [6, 6]
        for _ in range(25):
            actor.step()
        # both environments ended an episode by now (delivered or cut at 25 steps)
        assert actor.episodes >= 2
        assert all(env.steps < 25 for env in actor.envs)
        records = actor.control.drain_episodes()
        assert len(records) == actor.episodes
        assert all(e.phase == 6 and e.length <= 25 and not e.is_eval for e in records)
        # each record carries the Ape-X rate of the env that played it
        rates = set(actor.core.explorer.epsilon)
        assert rates == {epsilon_for_actor(0, 2), epsilon_for_actor(1, 2)}
        assert {e.epsilon for e in records} <= rates
        assert any(e.length == 25 for e in records) or all(e.ret == 1.0 for e in records)
        actor.control.phase_cell[0] = 1           # the curriculum reached the full task
        for _ in range(26):
            actor.step()
        assert [env.phase for env in actor.envs] == [1, 1]
