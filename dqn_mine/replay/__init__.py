"""Shared-memory prioritised replay (Ape-X style): ring storage, n-step writers, sum/min trees.

Five small modules, each swappable (after TorchRL's split):

=================  ===================================================================
``tree``           :class:`SumTree` (binary), :class:`MinTree` (32-ary): numpy, vectorised per batch
``storage``        :class:`ReplayLayout` (what to allocate), :class:`ReplayStorage` (the arrays)
``writer``         :class:`NStepWriter`: one per environment stream, lives in an actor process
``sampler``        :class:`PrioritizedReplay`, :class:`Batch`, :func:`beta_at`: the learner's side
``snapshot``       the replay on disk (``--save-replay``): saved with the checkpoint, read on resume
=================  ===================================================================

Wiring (the runner owns the shared memory; see ``dqn_mine.shared``)::

    layout = ReplayLayout(num_streams=S, stream_capacity=M, frame_shape=FRAME_SHAPE,
                          history_len=20, n_step=6, gamma=0.99, frame_stack=1)
    blocks = SharedBlocks.create(layout.block_specs())     # runner; frames are NOT pre-touched
    storage = ReplayStorage(layout, blocks)                # any process, after SharedBlocks.attach

    # actor process, one writer per environment (= stream k, slots [k*M, (k+1)*M))
    w = NStepWriter(storage, stream=k, eta=1e-5, flush_every=64)
    w.begin_episode(frame, carrying)                       # s_0
    w.append(q_values, action, reward, frame, carrying, terminated, truncated, next_q=None)
    w.history()                                            # int8[h], oldest first, -1 = none

    # learner process: the only owner of the trees, so no lock on the sampling path
    replay = PrioritizedReplay(storage, zeta=0.6, eta=1e-5, seed=0)
    replay.ingest()                                        # cheap; call before every sample
    out = Batch.empty(layout, 32)                          # optional: reuse the batch arrays
    batch = replay.sample(32, beta=beta_at(update, total_updates, 0.4), out=out)
    replay.update_priorities(batch.indices, td_abs, batch.stamps)  # queued: any thread

``update_priorities`` only queues ``(|delta| + eta)^zeta``; the trees change at the next
``ingest()`` (merged with the new and overwritten transitions into one tree update) or
``sample()``, in the thread that samples. So a learner that samples in a background thread can
report priorities from its training thread without a lock. A slot whose transition was
overwritten meanwhile stays dead, and with the batch's ``stamps`` a slot already refilled keeps
its new transition's priority (the update belongs to the old one).
``apply_priority_updates()`` applies the queue right away.

Data layout. Stream ``k`` writes its frames in order; frame number ``t`` (counted since the stream
began, across episodes) lives in slot ``k*M + t % M``. Each slot holds one frame and the state
that goes with it (carrying flag, action history, step within the episode), written when the frame
is appended, plus the transition that *starts* at that frame (action, n-step return, discount,
offset ``boot_off`` and slot ``boot`` of the bootstrap frame, the actor's initial priority),
written when it is complete. The bootstrap state s_{t+k} is just slot ``t+k``: frames are stored
once. An
episode-final frame starts no transition (``boot_off == 0``, never sampled).

Publication, without locks (one writer per stream): per stream two int64 counters, ``cursor``
(frames claimed: bumped *before* a frame's slot is overwritten) and ``published`` (frames whose
transition metadata is final: bumped *after* it is written). The learner's :meth:`ingest` adds
transitions in ``[old published, published)`` and zeroes those whose window a claimed frame
overwrote: transition ``t`` is alive while ``t - (frame_stack - 1) >= cursor - M``. With one ring
per stream, overwriting slot ``s`` therefore kills only the transition starting at ``s`` (for
``frame_stack == 1``; the ``f - 1`` following ones otherwise): every later frame of its window is
newer than ``s`` and is overwritten later, every transition starting earlier was killed when its own
slot was overwritten (``tests/test_replay_storage.py`` checks it). A writer racing a sample is
caught by re-reading the cursors after gathering: such samples get weight 0 and priority 0.
The ordering relies on x86's store and load ordering (numpy has no fences).

Batches. :class:`Batch` is a NamedTuple of numpy arrays (``obs`` uint8 [B, 3f, H, W], ``history``
int8 [B, h], ``carrying`` f32 [B], ``action`` i64 [B], ``ret`` f32 [B], ``discount`` f32 [B] =
gamma^k or 0 when the episode terminated in the window, ``next_obs``, ``next_history``,
``next_carrying``, ``weights`` f32 [B], ``indices`` i64 [B]). ``sample(..., out=batch)`` refills
an existing Batch in place (no 5 MB allocations per batch of 512; ``out`` may hold numpy views of
pinned torch tensors, C-contiguous). IS weights are ``(p_i / p_min)^-beta`` = ``(N P(i))^-beta``
over its maximum, with ``p_min`` from the min-tree; a sample whose window a writer overwrote while
it was gathered has weight 0 (rare: only the oldest transitions of a stream, between ingests).

Episode ends. ``terminated``: the return is cut and ``discount`` is 0 for every window that reaches
the terminal state. ``truncated``: the windows end at the last frame and bootstrap from it
(``discount`` gamma^k, k < n). An episode-final frame starts no transition. Frame stacking
(``frame_stack`` f > 1) stacks s_{t-f+1..t} within the episode, zeros before its first frame.

Writers. Call ``begin_episode`` for every episode (an unfinished previous one is dropped: its last
n transitions never complete). ``append`` copies the frame into shared memory at once; the rest
is published in blocks of ``flush_every`` steps and at episode ends (``flush()`` forces it). A
transition becomes visible once the actor has acted in s_{t+n}: its Q values give the bootstrap
term of the initial priority. ``storage.total_written()`` counts published env steps.
"""

from dqn_mine.replay import snapshot
from dqn_mine.replay.sampler import Batch, PrioritizedReplay, beta_at
from dqn_mine.replay.storage import ReplayLayout, ReplayStorage
from dqn_mine.replay.tree import MinTree, SumTree
from dqn_mine.replay.writer import NStepWriter

__all__ = ["Batch", "MinTree", "NStepWriter", "PrioritizedReplay", "ReplayLayout", "ReplayStorage",
           "SumTree", "beta_at", "snapshot"]
