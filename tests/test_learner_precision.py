"""The learner's bfloat16 path against the plain float32 update (the reference): same targets,
loss and gradients within bfloat16's precision, the same greedy actions after training a small
problem, exact resumption from float32 checkpoints, and the choice of precision by hardware.

bfloat16 runs on every CPU torch supports (emulated where not native), so these run on CI.
"""

import copy

import numpy as np
import pytest
import torch

from dqn_mine.agent.learning import DQNUpdater, double_dqn_target
from dqn_mine.agent.network import DuelingQNetwork, WorkingCopy
from dqn_mine.config import ConfigError, native_bf16, parse_args, resolve_learner_precision
from dqn_mine.replay import Batch


def frames_batch(b: int, seed: int = 0, ret_scale: float = 1.0) -> Batch:
    """Random frames and histories, rewards in [0, 1), a few terminal windows."""
    rng = np.random.default_rng(seed)
    frames = lambda: rng.integers(0, 256, (b, 3, 44, 76), dtype=np.uint8)  # noqa: E731
    hist = lambda: rng.integers(-1, 6, (b, 20)).astype(np.int8)  # noqa: E731
    discount = np.where(rng.random(b) < 0.2, 0.0, 0.99 ** 6).astype(np.float32)
    return Batch(frames(), hist(), rng.integers(0, 2, b).astype(np.float32),
                 rng.integers(0, 6, b), (ret_scale * rng.random(b)).astype(np.float32), discount,
                 frames(), hist(), rng.integers(0, 2, b).astype(np.float32),
                 rng.uniform(0.3, 1.0, b).astype(np.float32), np.arange(b))


def pair(**kw):
    """A float32 and a bfloat16 updater starting from the same weights."""
    torch.manual_seed(0)
    net = DuelingQNetwork()
    return (DQNUpdater(copy.deepcopy(net), precision="float32", **kw),
            DQNUpdater(copy.deepcopy(net), precision="bfloat16", **kw))


def grads(updater):
    return torch.cat([p.grad.flatten() for p in updater.online.parameters()])


def test_working_copy_computes_the_master_network():
    torch.manual_seed(0)
    net = DuelingQNetwork()
    work = WorkingCopy(net, torch.bfloat16)
    assert work.net.conv[0].weight.dtype == torch.bfloat16
    assert work.net.value[2].weight.dtype == torch.float32      # output layers stay float32
    b = frames_batch(64)
    args = (torch.from_numpy(b.obs), torch.from_numpy(b.history), torch.from_numpy(b.carrying))
    with torch.no_grad():
        q32, q16 = net(*args), work.net(*args)
    assert q16.dtype == torch.float32
    scale = q32.abs().max().item()
    assert (q16 - q32).abs().max().item() < 0.02 * scale
    # the folded input scale: the copy's first layer holds the master's weights / 255
    assert torch.allclose(work.net.conv[0].weight.float(), net.conv[0].weight / 255,
                          rtol=1e-2, atol=1e-6)


def test_bfloat16_targets_loss_and_gradients_match_the_float32_reference():
    ref, fast = pair(lr=1e-3)
    batch = frames_batch(64, seed=1)
    loss32, td32, q32, _, tb32 = ref.backward(batch)
    loss16, td16, q16, _, tb16 = fast.backward(batch)
    y32 = double_dqn_target(ref.online, ref.target, tb32)
    y16 = double_dqn_target(fast._work.net, fast._work_target.net, tb16)
    assert y16.dtype == torch.float32 and q16.dtype == torch.float32
    np.testing.assert_allclose(y16.numpy(), y32.numpy(), atol=5e-3)
    np.testing.assert_allclose(q16.numpy(), q32.numpy(), atol=5e-3)
    assert loss16.item() == pytest.approx(loss32.item(), rel=2e-2)
    g32, g16 = grads(ref), grads(fast)
    cosine = torch.nn.functional.cosine_similarity(g32, g16, dim=0).item()
    assert cosine > 0.995
    assert (g16.norm() / g32.norm()).item() == pytest.approx(1.0, abs=0.03)
    # the gradient of each parameter lands on the master weight of the same shape, in float32
    for master in fast.online.parameters():
        assert master.grad.dtype == torch.float32 and master.grad.shape == master.shape


def test_bfloat16_update_reports_like_the_reference_and_moves_the_working_copy():
    ref, fast = pair(lr=1e-3, max_grad_norm=40.0, target_update_interval=2)
    batch = frames_batch(32, seed=2)
    out32, out16 = ref.update(batch), fast.update(batch)
    for key in ("loss", "mean_q", "sampled_reward", "grad_norm"):
        assert out16[key] == pytest.approx(out32[key], rel=3e-2, abs=1e-3), key
    np.testing.assert_allclose(out16["td_abs"], out32["td_abs"], atol=5e-3)
    # the working copy took the new master weights (conv1 with the folded 1/255 scale)
    w = fast._work.net.conv[0].weight.float()
    assert torch.allclose(w, fast.online.conv[0].weight.detach() / 255, rtol=1e-2, atol=1e-6)
    fast.update(batch)                    # second update: target sync, working target follows
    assert torch.equal(fast._work_target.net.value[2].weight, fast.online.value[2].weight)


def test_bfloat16_learns_the_same_greedy_actions_on_a_small_problem():
    """Four scenes (frames of one colour each) and six actions; the right action ends the episode
    with reward 1, the others give 0 and stay. Q*(s, right) = 1, Q*(s, other) = gamma * 1."""
    rng = np.random.default_rng(0)
    colours = np.array([[200, 30, 30], [30, 200, 30], [30, 30, 200], [200, 200, 30]], np.uint8)
    right = np.array([0, 3, 5, 2])
    gamma = 0.9

    def batch(b: int) -> Batch:
        s = rng.integers(0, 4, b)
        a = rng.integers(0, 6, b)
        obs = np.broadcast_to(colours[s][:, :, None, None], (b, 3, 44, 76)).copy()
        obs = np.clip(obs + rng.integers(-20, 21, obs.shape), 0, 255).astype(np.uint8)
        hit = a == right[s]
        hist = np.full((b, 20), -1, np.int8)
        return Batch(obs, hist, np.zeros(b, np.float32), a, hit.astype(np.float32),
                     np.where(hit, 0.0, gamma).astype(np.float32), obs, hist,
                     np.zeros(b, np.float32), np.ones(b, np.float32), np.arange(b))

    # lr 3e-4: at 1e-3 this problem can kill every first-layer unit for a colour in either
    # precision (seen in bfloat16 at one seed), a fact about the learning rate, not the path
    ref, fast = pair(lr=3e-4, target_update_interval=50)
    for _ in range(500):
        b = batch(32)
        ref.update(b)
        fast.update(b)
    probe = batch(64)
    args = (torch.from_numpy(probe.obs), torch.from_numpy(probe.history),
            torch.from_numpy(probe.carrying))
    scene = [int(np.argmax([np.abs(o[:, 0, 0].astype(int) - c).sum() < 70 for c in colours]))
             for o in probe.obs]
    with torch.no_grad():
        q32, q16 = ref.online(*args).numpy(), fast.online(*args).numpy()
        greedy_work = fast._work.net(*args).argmax(1).numpy()
    greedy32, greedy16 = q32.argmax(1), q16.argmax(1)
    assert (greedy32 == right[scene]).all()
    q_star = np.full_like(q32, gamma)
    q_star[np.arange(len(scene)), right[scene]] = 1.0
    np.testing.assert_allclose(q16, q_star, atol=0.05)     # both learned Q*, not just argmax
    np.testing.assert_allclose(q32, q_star, atol=0.05)
    assert (greedy16 == greedy32).all() and (greedy_work == greedy32).all()


def test_bfloat16_resumes_from_a_float32_checkpoint():
    ref, fast = pair(lr=1e-3, target_update_interval=3)
    for seed in range(2):
        ref.update(frames_batch(16, seed=seed))
    fast.load_state_dict(ref.state_dict())
    assert fast.steps == 2
    for a, b in zip(fast.online.parameters(), ref.online.parameters()):
        assert torch.equal(a, b)
    # the working copies were refreshed from the loaded weights
    assert torch.equal(fast._work.net.value[2].weight, ref.online.value[2].weight)
    assert torch.equal(fast._work_target.net.value[2].weight, ref.target.value[2].weight)
    out32, out16 = ref.update(frames_batch(16, seed=5)), fast.update(frames_batch(16, seed=5))
    assert out16["loss"] == pytest.approx(out32["loss"], rel=3e-2, abs=1e-4)


def test_precision_choice_and_errors():
    assert resolve_learner_precision("float32", "cpu") == "float32"
    assert resolve_learner_precision("bfloat16", "cpu") == "bfloat16"
    assert resolve_learner_precision("auto", "cpu") == ("bfloat16" if native_bf16()
                                                        else "float32")
    with pytest.raises(ConfigError, match="--precision"):
        parse_args(["--precision", "fp8"])
    with pytest.raises(ValueError, match="precision"):
        DQNUpdater(DuelingQNetwork(), precision="half")


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available() or not torch.cuda.is_bf16_supported(),
                    reason="needs CUDA with bfloat16")
def test_bfloat16_on_cuda_matches_the_float32_reference_on_cpu():
    torch.manual_seed(0)
    net = DuelingQNetwork()
    ref = DQNUpdater(copy.deepcopy(net), lr=1e-3, max_grad_norm=40.0)
    gpu = DQNUpdater(copy.deepcopy(net), lr=1e-3, max_grad_norm=40.0, device="cuda",
                     precision="bfloat16")
    for seed in range(3):
        batch = frames_batch(32, seed=seed)
        out32, out16 = ref.update(batch), gpu.update(batch)
        assert out16["loss"] == pytest.approx(out32["loss"], rel=3e-2, abs=1e-4)
        np.testing.assert_allclose(out16["td_abs"], out32["td_abs"], atol=1e-2)
