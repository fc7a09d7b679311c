"""dqn_mine.shared: allocation, attachment from spawned processes, cleanup, free space."""

import multiprocessing as mp
import os
import subprocess
import sys
import time

import numpy as np
import pytest

from dqn_mine.replay import ReplayLayout
from dqn_mine.shared import (
    SHM_DIR,
    BlockSpec,
    SharedBlocks,
    SharedMemoryError,
    check_free_space,
    leftover_segments,
    stale_segments,
)

SPECS = [BlockSpec("x", (4, 3), "float32", np.nan), BlockSpec("n", (5,), "int64", 7),
         BlockSpec("raw", (16,), "uint8", None), BlockSpec("empty", (0, 3), "int8", -1)]


def _mine(blocks):
    return set(blocks._names.values())


def test_create_fills_magic_values_and_unlinks():
    with SharedBlocks.create(SPECS) as blocks:
        names = _mine(blocks)
        assert names <= set(leftover_segments())
        assert np.isnan(blocks["x"]).all() and (blocks["n"] == 7).all()
        assert blocks["empty"].shape == (0, 3) and "raw" in blocks
        assert blocks.nbytes == 4 * 3 * 4 + 5 * 8 + 16
    assert not names & set(leftover_segments())


def test_no_leftovers_after_an_exception():
    with pytest.raises(RuntimeError, match="boom"):
        with SharedBlocks.create(SPECS) as blocks:
            names = _mine(blocks)
            view = blocks["x"][1:]                 # a live view must not block the unlink
            raise RuntimeError("boom")
    del view
    assert not names & set(leftover_segments())


def test_duplicate_names_rejected():
    with pytest.raises(ValueError):
        SharedBlocks.create([BlockSpec("a", (1,), "uint8"), BlockSpec("a", (2,), "uint8")])


def test_too_little_shm_gives_a_clear_error():
    with pytest.raises(SharedMemoryError, match="replay-capacity") as err:
        check_free_space(1 << 60)
    assert "/dev/shm" in str(err.value)
    with pytest.raises(SharedMemoryError):
        SharedBlocks.create([BlockSpec("huge", (1 << 50,), "uint8")])   # nothing allocated
    assert not [n for n in leftover_segments() if n.endswith("_huge")]


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def _segment(name: str, nbytes: int) -> str:
    """A segment as the kernel keeps one: a file in /dev/shm (what a SIGKILLed run leaves)."""
    file = os.path.join(SHM_DIR, name)
    with open(file, "wb") as f:
        f.write(b"\0" * nbytes)
    return file


def test_clean_removes_segments_of_dead_runs_only():
    dead = _segment(f"dqnmine_{_dead_pid()}_cafe0000_frames", 3 << 20)
    live = _segment(f"dqnmine_{os.getpid()}_cafe0001_frames", 1024)
    try:
        stale = stale_segments()
        assert os.path.basename(dead) in stale and os.path.basename(live) not in stale
        with pytest.raises(SharedMemoryError, match="python -m dqn_mine.clean. frees 3.0 MiB"):
            check_free_space(1 << 60)
        dry = run_cli("clean", "--dry-run")
        assert os.path.basename(dead) in dry.stdout and os.path.exists(dead)
        out = run_cli("clean")
        assert os.path.basename(dead) in out.stdout and "freed" in out.stdout
        assert not os.path.exists(dead) and os.path.exists(live)   # a live run is never touched
        assert os.path.basename(live) not in out.stdout
    finally:
        for file in (dead, live):
            if os.path.exists(file):
                os.unlink(file)


def run_cli(module: str, *args: str) -> subprocess.CompletedProcess:
    res = subprocess.run([sys.executable, "-m", f"dqn_mine.{module}", *args],
                         capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    return res


def _child(handle, q):
    blocks = SharedBlocks.attach(handle)
    q.put((float(blocks["x"][2, 1]), int(blocks["n"].sum())))
    blocks["raw"][:] = 9                           # visible to the parent
    blocks.close()                                 # a child never unlinks


def test_spawned_process_attaches_and_writes():
    ctx = mp.get_context("spawn")
    with SharedBlocks.create(SPECS) as blocks:
        blocks["x"][2, 1] = 1.5
        q = ctx.Queue()
        p = ctx.Process(target=_child, args=(blocks.handle(), q))
        p.start()
        assert q.get(timeout=60) == (1.5, 35)
        p.join(timeout=60)
        assert p.exitcode == 0
        assert (blocks["raw"] == 9).all()
        assert _mine(blocks) <= set(leftover_segments())   # the child's close kept them
        names = _mine(blocks)
    assert not names & set(leftover_segments())


def test_full_size_replay_is_created_quickly_and_lazily():
    """Capacity 2^20 (about 10.5 GB of frames): creation must not touch the frame pages."""
    layout = ReplayLayout(num_streams=8, stream_capacity=2 ** 17)
    st = os.statvfs("/dev/shm")
    if st.f_bavail * st.f_frsize < layout.nbytes:
        pytest.skip("/dev/shm smaller than a full replay")
    t0 = time.perf_counter()
    with SharedBlocks.create(layout.block_specs()) as blocks:
        elapsed = time.perf_counter() - t0
        names = _mine(blocks)
        # pages actually allocated to the segments (other users of /dev/shm do not count)
        committed = sum(os.stat(os.path.join("/dev/shm", n.lstrip("/"))).st_blocks * 512
                        for n in names)
    assert elapsed < 5.0
    assert committed < 2 ** 28                     # metadata only (~45 MB), not 10.5 GB
    assert not names & set(leftover_segments())
