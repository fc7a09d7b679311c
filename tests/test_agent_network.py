"""The dueling network: shapes, input encoding, dueling combination."""

import pytest
import torch

from dqn_mine.agent.network import DuelingQNetwork, one_hot_history


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


def test_bfloat16_weights_give_close_q_values_and_the_same_greedy_actions():
    """Actors may act with a bfloat16 copy of the network (--actor-precision): the input is
    converted to the weights' dtype inside, and the Q-values stay within bfloat16's precision."""
    torch.manual_seed(0)
    net = DuelingQNetwork().eval()
    low = DuelingQNetwork().eval()
    low.load_state_dict(net.state_dict())
    low.to(torch.bfloat16)
    obs, history, carrying = inputs(64)
    with torch.inference_mode():
        q32, q16 = net(obs, history, carrying), low(obs, history, carrying)
    assert q16.dtype == torch.bfloat16 and q32.dtype == torch.float32
    scale = q32.abs().max().item()
    assert (q16.float() - q32).abs().max().item() < 0.02 * scale
    margin = q32.topk(2, dim=1).values.diff(dim=1).abs().squeeze(1)   # best minus second best
    clear = margin > 0.05 * scale                   # rounding cannot swap a clear winner
    assert clear.sum() > 16
    assert torch.equal(q16.float().argmax(1)[clear], q32.argmax(1)[clear])
