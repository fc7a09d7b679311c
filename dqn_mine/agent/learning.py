"""The learning maths: n-step double-DQN targets, the IS-weighted Huber loss, DQfD's margin
loss, the Ape-X exploration rates and one Adam update (:class:`DQNUpdater`, float32 or bfloat16
compute). Pure functions of tensors: the processes around them live in ``dqn_mine.system``.

A batch carries a per-sample ``discount``: gamma**k when the n-step window ended after k steps
without termination (k = n, or fewer when the episode was truncated: a time limit still
bootstraps), and 0 when the episode terminated inside the window (nothing to bootstrap from).
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from dqn_mine.agent.network import WorkingCopy


class TensorBatch(NamedTuple):
    """A replay batch on the learner's device (field meanings as in the replay's ``Batch``).

    ``indices`` stays a numpy array on the host: it is only used to send priorities back.
    """

    obs: torch.Tensor            # uint8 [B, 3f, H, W]
    history: torch.Tensor        # int8 [B, h], -1 = no action yet
    carrying: torch.Tensor       # float32 [B]
    action: torch.Tensor         # int64 [B]
    ret: torch.Tensor            # float32 [B], discounted n-step return
    discount: torch.Tensor       # float32 [B], gamma**k, 0 after termination
    next_obs: torch.Tensor       # uint8 [B, 3f, H, W]
    next_history: torch.Tensor   # int8 [B, h]
    next_carrying: torch.Tensor  # float32 [B]
    weights: torch.Tensor        # float32 [B], importance-sampling weights (max 1)
    indices: np.ndarray          # int64 [B], replay slots (host side)
    demo: torch.Tensor | None = None   # bool [B], a demonstration's transition (None: none)


def batch_to_device(batch, device: str | torch.device) -> TensorBatch:
    """Numpy batch (any NamedTuple with TensorBatch's fields) -> TensorBatch on ``device``.

    On CPU the tensors share memory with the numpy arrays (no copy). On CUDA they go through pinned
    memory with ``non_blocking=True``, so a background sampling thread can queue the copy and the
    learner's stream orders it before first use.
    """
    device = torch.device(device)
    fields = {}
    for name in TensorBatch._fields:
        value = getattr(batch, name, None)
        if value is None:
            continue
        if name == "indices":
            fields[name] = np.asarray(value)
            continue
        tensor = torch.as_tensor(np.ascontiguousarray(value))
        if device.type == "cuda":
            tensor = tensor.pin_memory().to(device, non_blocking=True)
        fields[name] = tensor.to(device)
    return TensorBatch(**fields)


# -- targets and loss --------------------------------------------------------------------------

def nstep_return(rewards: Sequence[float], gamma: float,
                 terminated_at: int | None = None) -> tuple[float, float]:
    """Reference n-step return and bootstrap discount of one window (for tests and writers).

    ``rewards`` are the k <= n rewards that followed the start state (k < n when the episode was
    truncated). ``terminated_at`` is the index of the reward whose step terminated the episode:
    later rewards are ignored and the discount is 0. Otherwise the discount is gamma**k.
    """
    if terminated_at is not None:
        rewards = rewards[:terminated_at + 1]
    ret = sum(gamma ** k * float(r) for k, r in enumerate(rewards))
    discount = 0.0 if terminated_at is not None else gamma ** len(rewards)
    return ret, discount


def q_of(net: nn.Module, batch: TensorBatch, next_state: bool = False) -> torch.Tensor:
    """Q-values [B, A] of the start states (or of the n-th next states)."""
    if next_state:
        return net(batch.next_obs, batch.next_history, batch.next_carrying)
    return net(batch.obs, batch.history, batch.carrying)


@torch.no_grad()
def double_dqn_target(online: nn.Module, target: nn.Module, batch: TensorBatch) -> torch.Tensor:
    """ret + discount * Q_target(s', argmax_a Q_online(s', a)) -> [B]."""
    best = q_of(online, batch, next_state=True).argmax(dim=1, keepdim=True)  # [B, 1]
    bootstrap = q_of(target, batch, next_state=True).gather(1, best).squeeze(1)  # [B]
    return batch.ret + batch.discount * bootstrap  # [B]


def margin_loss(q: torch.Tensor, action: torch.Tensor, margin: float) -> torch.Tensor:
    """DQfD's large-margin loss per sample: max_a [Q(s, a) + l(a_E, a)] - Q(s, a_E), with
    l = ``margin`` for every action but the demonstrated a_E, 0 for it. Zero once a_E beats
    every other action by the margin. ``q`` [B, A], ``action`` [B] -> [B]."""
    taken = action.long().unsqueeze(1)                                  # [B, 1]
    bonus = torch.full_like(q, margin).scatter_(1, taken, 0.0)          # [B, A]
    return (q + bonus).max(dim=1).values - q.gather(1, taken).squeeze(1)


def td_loss(online: nn.Module, target: nn.Module, batch: TensorBatch,
            demo_margin: float = 0.8, demo_weight: float = 0.0):
    """IS-weighted Huber loss, plus ``demo_weight`` x the margin loss on the batch's
    demonstrations -> (loss scalar, |TD error| [B] detached, Q(s, a) [B] detached, margin loss
    summed over the demonstrations, detached scalar)."""
    y = double_dqn_target(online, target, batch)  # [B]
    q = q_of(online, batch)  # [B, A]
    q_taken = q.gather(1, batch.action.long().unsqueeze(1)).squeeze(1)  # [B]
    per_sample = F.smooth_l1_loss(q_taken, y, reduction="none")  # [B]
    margin_sum = torch.zeros((), device=q.device)
    if batch.demo is not None and demo_weight:
        supervised = margin_loss(q.float(), batch.action, demo_margin) * batch.demo  # [B]
        per_sample = per_sample + demo_weight * supervised
        margin_sum = supervised.detach().sum()
    loss = (batch.weights * per_sample).mean()
    return loss, (y - q_taken).detach().abs(), q_taken.detach(), margin_sum


# -- exploration -------------------------------------------------------------------------------

def epsilon_for_actor(i: int, n: int, base: float = 0.4, alpha: float = 7.0) -> float:
    """Ape-X per-actor epsilon: base**(1 + alpha * i / (n - 1)); a single actor gets ``base``."""
    if n <= 1:
        return base
    return base ** (1.0 + alpha * i / (n - 1))


PRECISIONS = ("float32", "bfloat16")


# -- one learner update ------------------------------------------------------------------------

class DQNUpdater:
    """Online and target networks, Adam, target sync every ``target_update_interval`` updates.

    ``max_grad_norm`` clips the global gradient norm (None or 0: no clipping). See
    ``Config.max_grad_norm`` for the chosen default.

    ``precision`` "float32" is the plain update, the reference every faster path is tested
    against. "bfloat16" computes forward and backward in working copies of the networks whose
    convolutions and first stream layers hold bfloat16 (``network.WorkingCopy``), while the
    output layers, the targets, the loss, the master weights and Adam stay float32: the master
    gradients are the working copy's, and after each step the working copy takes the new
    weights. Where the hardware computes bfloat16 natively this is 1.3-1.6x faster at batch 32
    and 2x at batch 256 (``python -m dqn_mine.bench --only learner``, docs/learner.md).
    """

    def __init__(self, net: nn.Module, lr: float = 3e-5, target_update_interval: int = 2500,
                 device: str | torch.device = "cpu",
                 max_grad_norm: float | None = None, precision: str = "float32",
                 demo_margin: float = 0.8, demo_weight: float = 0.0):
        if precision not in PRECISIONS:
            raise ValueError(f"precision must be one of {PRECISIONS}, not {precision!r}")
        self.device = torch.device(device)
        self.online = net.to(self.device)
        self.target = copy.deepcopy(self.online).requires_grad_(False)
        self.precision = precision
        lowered = precision == "bfloat16"
        # fused Adam: one kernel for all parameters; same update rule as the plain loop
        self.optimizer = torch.optim.Adam(self.online.parameters(), lr=lr,
                                          **({"fused": True} if lowered else {}))
        self.target_update_interval = target_update_interval
        self.max_grad_norm = max_grad_norm
        self.demo_margin, self.demo_weight = demo_margin, demo_weight
        # every gradient step, demo pre-training included: what the target sync counts (the
        # run's own update count, which leaves pre-training out, is the Learner's)
        self.steps = 0
        self._work = self._work_target = None
        if lowered:
            self._work = WorkingCopy(self.online, torch.bfloat16)
            self._work_target = WorkingCopy(self.target, torch.bfloat16)

    def update(self, batch) -> dict[str, object]:
        """One gradient step on ``batch`` (numpy ``Batch`` or :class:`TensorBatch`).

        Returns ``loss``, ``mean_q``, ``sampled_reward`` (mean n-step return of the batch) as
        floats, ``grad_norm`` (float, nan when not clipping), ``demo_share`` (the batch's share
        of demonstrations), ``margin_loss`` (its mean over them, nan without any) and ``td_abs``
        (numpy float32 [B]) for priority feedback. One device-to-host transfer per update.
        """
        loss, td_abs, q_taken, margin_sum, batch = self.backward(batch)
        grad_norm = torch.full((), float("nan"), device=self.device)
        if self.max_grad_norm:
            grad_norm = nn.utils.clip_grad_norm_(self.online.parameters(), self.max_grad_norm)
        self.optimizer.step()
        if self._work is not None:
            self._work.pull()
        self.steps += 1
        if self.steps % self.target_update_interval == 0:
            self.sync_target()
        demos = batch.demo.sum() if batch.demo is not None else torch.zeros((), device=loss.device)
        stats = torch.stack([loss.detach(), q_taken.mean(), batch.ret.mean(),
                             grad_norm.detach().float(), demos.float(), margin_sum])  # [6]
        host = torch.cat([stats, td_abs.float()]).cpu().numpy()  # [6 + B], one transfer
        count = float(host[4])
        return {"loss": float(host[0]), "mean_q": float(host[1]),
                "sampled_reward": float(host[2]), "grad_norm": float(host[3]),
                "demo_share": count / len(td_abs),
                "margin_loss": float(host[5]) / count if count else float("nan"),
                "td_abs": host[6:].astype(np.float32)}

    def backward(self, batch):
        """Loss and gradients of ``batch`` on the master (``online``) parameters, no step.

        Returns (loss, |TD error| [B], Q(s, a) [B], the margin loss summed over the batch's
        demonstrations, the batch as tensors).
        """
        if not isinstance(batch, TensorBatch):
            batch = batch_to_device(batch, self.device)
        online, target = self.online, self.target
        if self._work is not None:
            online, target = self._work.net, self._work_target.net
            # converted once here instead of once per forward pass (s' is read twice)
            batch = batch._replace(obs=batch.obs.to(torch.bfloat16),
                                   next_obs=batch.next_obs.to(torch.bfloat16))
        loss, td_abs, q_taken, margin_sum = td_loss(online, target, batch, self.demo_margin,
                                                    self.demo_weight)
        # the network the loss went through; in bfloat16 the masters' gradients are then
        # replaced wholesale by push_gradients
        online.zero_grad(set_to_none=True)
        loss.backward()
        if self._work is not None:
            self._work.push_gradients()
        return loss, td_abs, q_taken, margin_sum, batch

    def sync_target(self) -> None:
        self.target.load_state_dict(self.online.state_dict())
        if self._work_target is not None:
            self._work_target.pull()

    def state_dict(self) -> dict:
        """Everything a checkpoint needs to continue exactly: networks, optimiser, counters."""
        return {"online": self.online.state_dict(), "target": self.target.state_dict(),
                "optimizer": self.optimizer.state_dict(), "updates": self.steps}

    def load_state_dict(self, state: dict) -> None:
        self.online.load_state_dict(state["online"])
        self.target.load_state_dict(state["target"])
        # torch's optimiser keeps (not copies) same-device state tensors: without a copy two
        # updaters loaded from one dict would share their Adam moments.
        self.optimizer.load_state_dict(copy.deepcopy(state["optimizer"]))
        self.steps = int(state["updates"])
        if self._work is not None:
            self._work.pull()
            self._work_target.pull()
