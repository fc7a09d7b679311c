"""The dueling network: shapes, input encoding, dueling combination."""

import copy

import pytest
import torch

from dqn_mine.agent.network import DuelingQNetwork, lower_heavy_layers, one_hot_history


def inputs(batch, frame_stack=1, history_len=20, seed=0):
    g = torch.Generator().manual_seed(seed)
    obs = torch.randint(0, 256, (batch, 3 * frame_stack, 44, 76), dtype=torch.uint8, generator=g)
    history = torch.randint(-1, 6, (batch, history_len), dtype=torch.int8, generator=g)
    carrying = torch.randint(0, 2, (batch,), generator=g).float()
    return obs, history, carrying


@pytest.mark.parametrize("frame_stack,history_len", [(1, 20), (4, 20), (1, 0), (4, 0)])
def test_shapes_follow_the_spec_table(frame_stack, history_len):
    net = DuelingQNetwork(frame_stack=frame_stack, history_len=history_len)
    obs, history, carrying = inputs(5, frame_stack, history_len)
    x = obs.float() / 255
    shapes = []
    for layer in net.conv:
        x = layer(x)
        if isinstance(layer, torch.nn.ReLU):
            shapes.append(tuple(x.shape[1:]))
    assert shapes == [(32, 10, 18), (64, 4, 8), (64, 2, 6)]
    assert net.conv_out == 768
    features = 768 + 6 * history_len + 1
    assert net.value[0].in_features == features and net.advantage[0].in_features == features
    assert net.value[-1].out_features == 1 and net.advantage[-1].out_features == 6
    q = net(obs, history, carrying)
    assert q.shape == (5, 6) and q.dtype == torch.float32


def test_one_hot_history_by_hand():
    history = torch.tensor([[-1, 0, 5], [2, -1, -1]], dtype=torch.int8)
    expected = torch.tensor([
        [0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 1],
        [0, 0, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0],
    ], dtype=torch.float32)
    assert torch.equal(one_hot_history(history, 6), expected)
    assert torch.equal(one_hot_history(history.long(), 6), expected)


def test_q_is_value_plus_centred_advantage_on_scaled_inputs():
    torch.manual_seed(0)
    net = DuelingQNetwork(history_len=2)
    obs, _, carrying = inputs(3, history_len=2)
    history = torch.tensor([[-1, 3], [0, 0], [-1, -1]], dtype=torch.int8)
    onehot = torch.zeros(3, 12)
    onehot[0, 6 + 3] = onehot[1, 0] = onehot[1, 6] = 1
    features = torch.cat([net.conv(obs.float() / 255), carrying[:, None], onehot], dim=1)
    value, advantage = net.value(features), net.advantage(features)
    expected = value + advantage - advantage.mean(dim=1, keepdim=True)
    q = net(obs, history, carrying)
    assert torch.allclose(q, expected, atol=1e-6)
    assert torch.allclose(q.mean(dim=1), value.squeeze(1), atol=1e-6)


def test_empty_history_slots_differ_from_any_action():
    torch.manual_seed(0)
    net = DuelingQNetwork(history_len=1)
    obs, _, carrying = inputs(1, history_len=1)
    outs = [net(obs, torch.tensor([[a]], dtype=torch.int8), carrying) for a in range(-1, 6)]
    for a in range(1, 7):
        assert not torch.allclose(outs[0], outs[a])


def test_lowered_network_keeps_float32_greedy_actions_at_sparse_reward_gaps():
    """Actors act with the heavy layers in bfloat16 (--precision). With Q-values near 0.4
    and gaps of ~1e-3 between the best actions, as in a 1,000-step sparse-reward task at gamma
    0.99, a network rounded to bfloat16 to its end ties or swaps its best actions (bfloat16's
    spacing at 0.4 is 0.002); with the output layers in float32 it picks the float32 argmax."""
    torch.manual_seed(0)
    net = DuelingQNetwork().eval()
    with torch.no_grad():
        net.value[2].bias.fill_(0.4)
        net.advantage[2].weight.mul_(0.05)
    lowered = lower_heavy_layers(copy.deepcopy(net), torch.bfloat16)
    all_bf16 = copy.deepcopy(net).to(torch.bfloat16)
    obs, history, carrying = inputs(256)
    with torch.inference_mode():
        q32, q_low, q_all = (n(obs, history, carrying) for n in (net, lowered, all_bf16))
    gaps = q32.topk(2, dim=1).values.diff(dim=1).abs().squeeze(1)
    assert gaps.median() < 0.003                           # the regime of interest
    assert q_low.dtype == torch.float32 and lowered.conv[0].weight.dtype == torch.bfloat16
    assert (q_low - q32).abs().max() < 1e-3
    assert torch.equal(q_low.argmax(1), q32.argmax(1))
    ties = (q_all == q_all.max(dim=1, keepdim=True).values).sum(1) > 1
    assert ties.float().mean() > 0.1                       # what the float32 output layers avoid
