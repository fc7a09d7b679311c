import os

import pytest

# llvmpipe spawns render threads per context; on a 2-core machine with several test processes that
# only adds contention (see the env benchmark for the measured choice).
os.environ.setdefault("LP_NUM_THREADS", "0")


@pytest.fixture
def noop_network():
    """Factory: a network whose greedy action is the no-op whatever it sees (the frame never
    changes), for tests of stuck policies."""
    import torch

    from dqn_mine.agent.network import DuelingQNetwork

    def make(frame_stack: int = 1, history_len: int = 20) -> DuelingQNetwork:
        net = DuelingQNetwork(frame_stack=frame_stack, history_len=history_len)
        with torch.no_grad():
            for p in net.parameters():
                p.zero_()
            net.advantage[-1].bias[5] = 1.0
        return net.eval()

    return make
