"""n-step double-DQN targets, the IS-weighted Huber loss, epsilon policies and the updater, against
values computed by hand. Q-functions are tiny lookup tables: Q(s, .) = table[s], with the state id
s carried in obs[:, 0, 0, 0]."""


import numpy as np
import pytest
import torch
from torch import nn

from dqn_mine.agent.learning import (
    DQNUpdater,
    TensorBatch,
    batch_to_device,
    double_dqn_target,
    epsilon_for_actor,
    nstep_return,
    td_loss,
)
from dqn_mine.agent.network import DuelingQNetwork
from dqn_mine.replay import Batch

GAMMA = 0.9


class TableQ(nn.Module):
    def __init__(self, table):
        super().__init__()
        self.table = nn.Parameter(torch.tensor(table, dtype=torch.float32))  # [S, A]

    def forward(self, obs, history, carrying):
        return self.table[obs[:, 0, 0, 0].long()]  # [B, A]


def table_batch(states, actions, rets, discounts, next_states, weights=None):
    b = len(states)
    as_obs = lambda s: np.array(s, dtype=np.uint8).reshape(b, 1, 1, 1)  # noqa: E731
    return Batch(obs=as_obs(states), history=np.zeros((b, 0), np.int8),
                 carrying=np.zeros(b, np.float32), action=np.array(actions, np.int64),
                 ret=np.array(rets, np.float32), discount=np.array(discounts, np.float32),
                 next_obs=as_obs(next_states), next_history=np.zeros((b, 0), np.int8),
                 next_carrying=np.zeros(b, np.float32),
                 weights=np.ones(b, np.float32) if weights is None else
                 np.array(weights, np.float32), indices=np.arange(b, dtype=np.int64))


# Online and target disagree about the best action in state 1 (online: action 1; target: 0).
ONLINE = [[0.0, 0.0, 0.0], [1.0, 5.0, 2.0], [4.0, -1.0, 0.5]]
TARGET = [[0.0, 0.0, 0.0], [10.0, 3.0, 7.0], [2.0, 8.0, -3.0]]


# -- n-step returns ----------------------------------------------------------------------------

def test_nstep_return_by_hand():
    assert nstep_return([0, 0, 1], GAMMA) == pytest.approx((0.81, 0.729))
    # terminated on the second step: later rewards (another episode) are cut, no bootstrap
    assert nstep_return([0, 1, 5], GAMMA, terminated_at=1) == pytest.approx((0.9, 0.0))
    # truncated after two of three steps: the window is short but still bootstraps
    assert nstep_return([0.5, 1], GAMMA) == pytest.approx((0.5 + 0.9, 0.81))


# -- targets -----------------------------------------------------------------------------------

def test_double_dqn_target_uses_online_argmax_and_target_value():
    online, target = TableQ(ONLINE), TableQ(TARGET)
    full, term, trunc = GAMMA ** 3, 0.0, GAMMA ** 2
    batch = batch_to_device(table_batch(
        states=[0, 0, 0, 0], actions=[0, 0, 0, 0], rets=[0.5, 1.0, 0.2, 0.0],
        discounts=[full, term, trunc, full], next_states=[1, 1, 1, 2]), "cpu")
    y = double_dqn_target(online, target, batch)
    expected = [0.5 + full * 3.0,    # online picks action 1, valued 3 by the target (not its 10)
                1.0,                 # terminated inside the window: return only
                0.2 + trunc * 3.0,   # truncated: bootstraps with the shorter discount
                0.0 + full * 2.0]    # state 2: online picks action 0, target says 2
    assert y.tolist() == pytest.approx(expected, rel=1e-6)
    assert not y.requires_grad


def test_td_loss_is_weighted_huber_by_hand():
    online, target = TableQ(ONLINE), TableQ(TARGET)
    # Q(s, a) taken: state 2, actions 0, 1, 2 -> 4.0, -1.0, 0.5; targets (discount 0) = returns
    rets, weights = [4.5, 1.0, 0.5], [1.0, 0.5, 0.25]
    batch = batch_to_device(table_batch([2, 2, 2], [0, 1, 2], rets, [0, 0, 0], [0, 0, 0],
                                        weights), "cpu")
    loss, td_abs, q_taken, _ = td_loss(online, target, batch)
    # deltas 0.5 (quadratic: 0.125), 2.0 (linear: 1.5), 0.0
    assert loss.item() == pytest.approx((1.0 * 0.125 + 0.5 * 1.5 + 0.25 * 0.0) / 3)
    assert td_abs.tolist() == pytest.approx([0.5, 2.0, 0.0])
    assert q_taken.tolist() == pytest.approx([4.0, -1.0, 0.5])
    assert not td_abs.requires_grad and not q_taken.requires_grad
    loss.backward()
    grad = torch.zeros(3, 3)
    # dL/dQ = w * clip(Q - y, -1, 1) / B, only at the taken entries of the start state
    grad[2] = torch.tensor([1.0 * -0.5, 0.5 * -1.0, 0.0]) / 3
    assert torch.allclose(online.table.grad, grad)
    assert target.table.grad is None


# -- exploration -------------------------------------------------------------------------------

def test_apex_epsilons():
    assert epsilon_for_actor(0, 1) == 0.4
    assert epsilon_for_actor(0, 8) == pytest.approx(0.4)
    assert epsilon_for_actor(3, 8) == pytest.approx(0.4 ** 4)
    assert epsilon_for_actor(7, 8) == pytest.approx(0.4 ** 8)
    assert epsilon_for_actor(1, 2, base=0.5, alpha=1) == pytest.approx(0.25)


# -- updater -----------------------------------------------------------------------------------

def random_batch(b=8, frame_stack=1, history_len=20, seed=0):
    rng = np.random.default_rng(seed)
    frames = lambda: rng.integers(0, 256, (b, 3 * frame_stack, 44, 76), dtype=np.uint8)  # noqa
    hist = lambda: rng.integers(-1, 6, (b, history_len)).astype(np.int8)  # noqa: E731
    return Batch(obs=frames(), history=hist(), carrying=rng.integers(0, 2, b).astype(np.float32),
                 action=rng.integers(0, 6, b), ret=rng.random(b).astype(np.float32),
                 discount=np.where(rng.random(b) < 0.3, 0.0, 0.99 ** 6).astype(np.float32),
                 next_obs=frames(), next_history=hist(),
                 next_carrying=rng.integers(0, 2, b).astype(np.float32),
                 weights=rng.random(b).astype(np.float32), indices=np.arange(b) * 3)


def test_batch_to_device_types():
    nb = random_batch(4)
    tb = batch_to_device(nb, "cpu")
    assert isinstance(tb, TensorBatch)
    assert tb.obs.dtype == torch.uint8 and tb.history.dtype == torch.int8
    assert tb.action.dtype == torch.int64 and tb.weights.dtype == torch.float32
    assert isinstance(tb.indices, np.ndarray) and tb.indices.tolist() == [0, 3, 6, 9]
    assert np.shares_memory(tb.obs.numpy(), nb.obs)  # CPU: no copy


def test_update_reports_pre_update_td_and_syncs_target():
    torch.manual_seed(0)
    up = DQNUpdater(DuelingQNetwork(), lr=1e-3, target_update_interval=2, max_grad_norm=10.0)
    batch = random_batch(8)
    _, td_before, q_before, _ = td_loss(up.online, up.target, batch_to_device(batch, "cpu"))
    out = up.update(batch)
    assert out["td_abs"].shape == (8,) and out["td_abs"].dtype == np.float32
    assert out["td_abs"] == pytest.approx(td_before.numpy(), rel=1e-5)
    assert out["mean_q"] == pytest.approx(q_before.mean().item(), rel=1e-5)
    assert out["sampled_reward"] == pytest.approx(batch.ret.mean(), rel=1e-6)
    assert np.isfinite(out["loss"]) and out["grad_norm"] > 0
    differ = lambda: any(not torch.equal(a, b) for a, b in  # noqa: E731
                         zip(up.online.state_dict().values(), up.target.state_dict().values()))
    assert up.steps == 1 and differ()  # online moved, target not yet synced
    up.update(batch)
    assert up.steps == 2 and not differ()  # synced after C = 2 updates


def test_state_dict_resumes_exactly():
    torch.manual_seed(0)
    a = DQNUpdater(DuelingQNetwork(history_len=0), lr=1e-3, target_update_interval=3)
    batches = [random_batch(4, history_len=0, seed=s) for s in range(4)]
    for b in batches[:2]:
        a.update(b)
    b_up = DQNUpdater(DuelingQNetwork(history_len=0), lr=1e-3, target_update_interval=3)
    b_up.load_state_dict(a.state_dict())
    assert b_up.steps == 2
    for b in batches[2:]:
        out_a, out_b = a.update(b), b_up.update(b)
        assert out_a["loss"] == out_b["loss"]
    for x, y in zip(a.state_dict()["online"].values(), b_up.state_dict()["online"].values()):
        assert torch.equal(x, y)


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_update_on_cuda_matches_cpu():
    torch.manual_seed(0)
    net = DuelingQNetwork()
    cpu = DQNUpdater(net, lr=1e-3, device="cpu")
    gpu = DQNUpdater(DuelingQNetwork(), lr=1e-3, device="cuda")
    gpu.load_state_dict(cpu.state_dict())
    batch = random_batch(16)
    out_c, out_g = cpu.update(batch), gpu.update(batch)
    assert out_g["td_abs"] == pytest.approx(out_c["td_abs"], rel=1e-3, abs=1e-4)


def test_updater_learns_a_chain_by_hand():
    """States 0 -> 1 -> 2 -> 3 (terminal on arrival, reward 1) under action 0; action 1 stays.

    Q*(s, 0) = gamma**(2 - s) and Q*(s, 1) = gamma * Q*(s, 0), for s = 0, 1, 2.
    """
    states = [0, 1, 2, 0, 1, 2]
    actions = [0, 0, 0, 1, 1, 1]
    next_states = [1, 2, 3, 0, 1, 2]
    rets = [0.0, 0.0, 1.0, 0.0, 0.0, 0.0]
    discounts = [GAMMA, GAMMA, 0.0, GAMMA, GAMMA, GAMMA]
    batch = table_batch(states, actions, rets, discounts, next_states)
    up = DQNUpdater(TableQ(np.zeros((4, 2))), lr=0.05, target_update_interval=10)
    for _ in range(1500):
        up.update(batch)
    q = up.online.table.detach().numpy()[:3]
    best = GAMMA ** (2 - np.arange(3))
    np.testing.assert_allclose(q, np.stack([best, GAMMA * best], axis=1), atol=0.02)
