"""Weight broadcast through shared memory: versions, torn-read protection, pick-up across a real
spawned process, no leftover segments."""

import multiprocessing as mp
import os
import time

import numpy as np
import pytest
import torch
from torch import nn

from dqn_mine.agent.network import DuelingQNetwork
from dqn_mine.shared import SharedBlocks, leftover_segments
from dqn_mine.system.weights import WeightBroadcast

CTX = mp.get_context("spawn")


def probe(seed=0):
    g = torch.Generator().manual_seed(seed)
    return (torch.randint(0, 256, (3, 3, 44, 76), dtype=torch.uint8, generator=g),
            torch.randint(-1, 6, (3, 20), dtype=torch.int8, generator=g), torch.tensor([0., 1, 0]))


def segment_names(blocks):
    return {n.lstrip("/") for n in blocks.handle()[1].values()}


@pytest.fixture
def net_and_blocks():
    torch.manual_seed(0)
    net = DuelingQNetwork()
    blocks = SharedBlocks.create(WeightBroadcast.specs(net))
    yield net, blocks
    names = segment_names(blocks)
    blocks.close()
    assert not names & set(leftover_segments())


def test_publish_then_pull_in_process(net_and_blocks):
    net, blocks = net_and_blocks
    broadcast = WeightBroadcast(blocks)
    assert np.isnan(blocks["weights"]).all()  # magic fill: never-published weights are obvious
    reader = DuelingQNetwork()
    assert broadcast.version() == 0 and broadcast.pull(reader, -1) is None  # nothing published
    assert broadcast.publish(net) == 1 and broadcast.version() == 1
    assert broadcast.pull(reader, -1) == 1
    assert torch.equal(reader(*probe()), net(*probe()))
    assert broadcast.pull(reader, 1) is None  # version did not move: no copy
    with torch.no_grad():
        net.value[-1].bias.add_(1.0)
    assert broadcast.publish(net) == 2 and broadcast.pull(reader, 1) == 2
    assert torch.equal(reader(*probe()), net(*probe()))


def test_pull_converts_into_a_bfloat16_reader(net_and_blocks):
    """An actor acting in bfloat16 reads the float32 vector into its bfloat16 tensors."""
    net, blocks = net_and_blocks
    broadcast = WeightBroadcast(blocks)
    broadcast.publish(net)
    reader = DuelingQNetwork().to(torch.bfloat16)
    assert broadcast.pull(reader, -1) == 1
    for ours, theirs in zip(reader.state_dict().values(), net.state_dict().values()):
        assert ours.dtype == torch.bfloat16
        assert torch.equal(ours, theirs.to(torch.bfloat16))


class InterruptedReader(WeightBroadcast):
    """A reader whose first copy is interleaved with a whole publish by the learner."""

    def __init__(self, blocks, writer, newer):
        super().__init__(blocks)
        self.writer, self.newer, self.copies = writer, newer, 0

    def _snapshot(self):
        self.copies += 1
        if self.copies == 1:
            self.flat[: len(self.flat) // 2].fill_(7.0)  # half of a write landed mid-copy
            super()._snapshot()
            self.writer.publish(self.newer)
        else:
            super()._snapshot()


def test_torn_read_is_retried(net_and_blocks):
    net, blocks = net_and_blocks
    writer = WeightBroadcast(blocks)
    writer.publish(net)
    newer = DuelingQNetwork()
    reader_net = DuelingQNetwork()
    reader = InterruptedReader(blocks, writer, newer)
    assert reader.pull(reader_net, 0) == 2 and reader.copies == 2
    assert torch.equal(reader_net(*probe()), newer(*probe()))


def test_pull_gives_up_while_a_publish_never_finishes(net_and_blocks):
    net, blocks = net_and_blocks
    broadcast = WeightBroadcast(blocks)
    broadcast.publish(net)
    blocks["weights_seq"][0] += 1  # a writer died mid-publish: odd forever
    reader = DuelingQNetwork()
    before = [p.clone() for p in reader.parameters()]
    assert broadcast.pull(reader, 0, timeout=0.05) is None
    assert all(torch.equal(a, b) for a, b in zip(before, reader.parameters()))


# -- across processes --------------------------------------------------------------------------

def _actor_child(handle, conn):
    torch.set_num_threads(1)
    blocks = SharedBlocks.attach(handle)
    try:
        broadcast, net, version = WeightBroadcast(blocks), DuelingQNetwork(), 0
        while True:
            wanted = conn.recv()
            if wanted is None:
                return
            deadline = time.monotonic() + 20
            while version < wanted and time.monotonic() < deadline:
                version = broadcast.pull(net, version) or version
                time.sleep(0.001)
            with torch.no_grad():
                conn.send((version, net(*probe()).numpy()))
    finally:
        blocks.close()


def test_spawned_actor_picks_up_new_versions(net_and_blocks):
    net, blocks = net_and_blocks
    broadcast = WeightBroadcast(blocks)
    parent, child = CTX.Pipe()
    proc = CTX.Process(target=_actor_child, args=(blocks.handle(), child), daemon=True)
    proc.start()
    try:
        for expected in (1, 2):
            if expected == 2:
                with torch.no_grad():
                    net.advantage[-1].weight.mul_(-2.0)
            assert broadcast.publish(net) == expected
            parent.send(expected)
            assert parent.poll(60), "child did not answer"
            version, q = parent.recv()
            assert version == expected
            with torch.no_grad():
                np.testing.assert_array_equal(q, net(*probe()).numpy())
        parent.send(None)
        proc.join(20)
        assert proc.exitcode == 0
    finally:
        if proc.is_alive():
            proc.kill()
            proc.join()


def _writer_child(handle, stop, published):
    torch.set_num_threads(1)
    blocks = SharedBlocks.attach(handle)
    try:
        broadcast, net = WeightBroadcast(blocks), nn.Linear(1000, 1000)
        k = 0
        while not stop.is_set():
            k += 1
            with torch.no_grad():
                for p in net.parameters():
                    p.fill_(k)  # every weight of version k equals k
            broadcast.publish(net)
            published.value = k
    finally:
        blocks.close()


def test_concurrent_publishes_never_give_a_torn_copy():
    net = nn.Linear(1000, 1000)  # 1M floats: a copy takes long enough to overlap a write
    blocks = SharedBlocks.create(WeightBroadcast.specs(net))
    names = segment_names(blocks)
    stop, published = CTX.Event(), CTX.Value("q", 0)
    proc = CTX.Process(target=_writer_child, args=(blocks.handle(), stop, published), daemon=True)
    proc.start()
    try:
        broadcast, version, pulls = WeightBroadcast(blocks), 0, 0
        deadline = time.monotonic() + 60
        while published.value < 1 and time.monotonic() < deadline:
            time.sleep(0.01)
        # At least 1.5 s of pulls against the writer, longer until three clean copies: on a busy
        # 2-core machine most copies overlap a write and are retried, so a fixed window is flaky.
        start = time.monotonic()
        while time.monotonic() < start + 30 and (pulls < 3 or time.monotonic() < start + 1.5):
            new = broadcast.pull(net, version)
            if new is not None:
                values = torch.cat([net.weight.reshape(-1), net.bias])
                assert values.min() == values.max() == new, "torn copy"
                version, pulls = new, pulls + 1
        assert pulls >= 3
    finally:
        stop.set()
        proc.join(20)
        if proc.is_alive():
            proc.kill()
            proc.join()
        blocks.close()
    assert proc.exitcode == 0
    assert not names & set(leftover_segments()), os.listdir("/dev/shm")
