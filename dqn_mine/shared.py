"""Every shared-memory block of a run is declared, created, attached and unlinked here.

Actors, learner and replay never call ``SharedMemory`` themselves: the process that owns a run
creates a :class:`SharedBlocks` from a list of :class:`BlockSpec`, hands ``blocks.handle()`` (a
small picklable value) to spawned children, and the children ``SharedBlocks.attach(handle)``.

Segments are named ``dqnmine_<pid>_<token>_<block>`` so a leftover is easy to spot in ``/dev/shm``.
The creator is registered with Python's resource tracker, so even after a ``kill -9`` of the owner
the tracker unlinks the segments. Spawned children share their parent's tracker, so their own
(idempotent) registration on attach is harmless and must not be undone: unregistering in a child
would drop the owner's safety net.
"""

from __future__ import annotations

import mmap
import os
import secrets
from collections.abc import Iterable
from dataclasses import dataclass
from multiprocessing import shared_memory

import numpy as np

SHM_PREFIX = "dqnmine_"
SHM_DIR = "/dev/shm"


class SharedMemoryError(RuntimeError):
    """Shared memory could not be allocated (usually: too little free space in /dev/shm)."""


@dataclass(frozen=True)
class BlockSpec:
    """One named array in shared memory.

    ``fill`` is written once at creation (e.g. a magic value so reading a never-written slot is
    obvious); ``None`` leaves the pages untouched, which matters for the multi-GB frame store:
    Linux only commits a shared page when it is first written, so the ring fills memory lazily.
    """

    name: str
    shape: tuple[int, ...]
    dtype: str
    fill: float | None = None

    @property
    def nbytes(self) -> int:
        return int(np.prod(self.shape, dtype=np.int64)) * np.dtype(self.dtype).itemsize


def human_bytes(nbytes: int) -> str:
    return f"{nbytes / 2**30:.2f} GiB" if nbytes >= 2**28 else f"{nbytes / 2**20:.1f} MiB"


def shm_free_bytes(path: str = SHM_DIR) -> int | None:
    """Free bytes in the shared-memory filesystem, or None where there is no such directory."""
    try:
        st = os.statvfs(path)
    except OSError:
        return None
    return st.f_bavail * st.f_frsize


def check_free_space(nbytes: int, path: str = SHM_DIR) -> None:
    """Fail early, with the remedy, if ``nbytes`` of shared memory cannot fit."""
    free = shm_free_bytes(path)
    if free is not None and nbytes > free:
        stale = stale_bytes(path)
        remedy = (f"`python -m dqn_mine.clean` frees {human_bytes(stale)} left by dead runs, or "
                  if stale else "")
        raise SharedMemoryError(
            f"the replay needs {human_bytes(nbytes)} of shared memory but {path} has only "
            f"{human_bytes(free)} free: {remedy}use a smaller --replay-capacity or enlarge {path} "
            f"(e.g. `mount -o remount,size=32G {path}` or docker --shm-size)"
        )


def _own_mapping(seg: shared_memory.SharedMemory) -> mmap.mmap:
    """A private mapping of the segment that lives exactly as long as the arrays built on it.

    NumPy keeps a reference to the buffer object but not a buffer export, so closing a
    SharedMemory while an array still views it unmaps memory under the array (a segfault on the
    next access). Arrays built on this mapping keep it alive; nothing ever closes it explicitly.
    The SharedMemory's own mapping and descriptor are released at once.
    """
    mapping = mmap.mmap(seg._fd, seg.size)  # type: ignore[attr-defined]
    seg.close()
    return mapping


class SharedBlocks:
    """A set of named numpy arrays living in shared memory."""

    def __init__(self, specs: Iterable[BlockSpec], names: dict[str, str],
                 segments: dict[str, shared_memory.SharedMemory], owner: bool):
        self.specs = {s.name: s for s in specs}
        self._names = names
        self._segments = segments
        self.owner = owner
        self.arrays: dict[str, np.ndarray] = {
            s.name: np.ndarray(s.shape, dtype=s.dtype, buffer=_own_mapping(segments[s.name]))
            for s in self.specs.values()
        }

    # -- creation and attachment -------------------------------------------------------------
    @classmethod
    def create(cls, specs: Iterable[BlockSpec]) -> SharedBlocks:
        """Allocate every block (after checking /dev/shm has room); the caller owns them."""
        specs = list(specs)
        if len({s.name for s in specs}) != len(specs):
            raise ValueError("duplicate shared block names")
        check_free_space(sum(s.nbytes for s in specs))
        token = f"{SHM_PREFIX}{os.getpid()}_{secrets.token_hex(4)}_"
        segments: dict[str, shared_memory.SharedMemory] = {}
        try:
            for s in specs:
                segments[s.name] = shared_memory.SharedMemory(
                    name=token + s.name, create=True, size=max(1, s.nbytes))
        except BaseException:
            for seg in segments.values():
                seg.close()
                seg.unlink()
            raise
        blocks = cls(specs, {k: v.name for k, v in segments.items()}, segments, owner=True)
        for s in specs:
            if s.fill is not None:
                blocks.arrays[s.name].fill(s.fill)
        return blocks

    def handle(self) -> tuple:
        """A picklable description that :meth:`attach` turns back into the same arrays."""
        return (tuple(self.specs.values()), dict(self._names))

    @classmethod
    def attach(cls, handle: tuple) -> SharedBlocks:
        specs, names = handle
        segments = {}
        for s in specs:
            segments[s.name] = shared_memory.SharedMemory(name=names[s.name], create=False)
        return cls(specs, names, segments, owner=False)

    # -- access ------------------------------------------------------------------------------
    def __getitem__(self, name: str) -> np.ndarray:
        return self.arrays[name]

    def __contains__(self, name: str) -> bool:
        return name in self.arrays

    @property
    def nbytes(self) -> int:
        return sum(s.nbytes for s in self.specs.values())

    # -- release -----------------------------------------------------------------------------
    def close(self) -> None:
        """Forget the arrays; the owner also unlinks the segments (the names disappear from
        /dev/shm at once, the memory when the last mapping of any process is gone)."""
        self.arrays = {}
        for seg in self._segments.values():
            if self.owner:
                try:
                    seg.unlink()
                except FileNotFoundError:
                    pass
        self._segments = {}

    def __enter__(self) -> SharedBlocks:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def leftover_segments(path: str = SHM_DIR) -> list:
    """Names of dqn_mine segments still present in /dev/shm (tests assert this stays empty)."""
    try:
        return sorted(n for n in os.listdir(path) if n.startswith(SHM_PREFIX))
    except FileNotFoundError:
        return []


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:        # another user's live process
        return True
    return True


def segment_pid(name: str) -> int | None:
    """The pid of the process that created the segment ``dqnmine_<pid>_...``, or None."""
    pid = name[len(SHM_PREFIX):].split("_", 1)[0]
    return int(pid) if pid.isdigit() else None


def stale_segments(path: str = SHM_DIR) -> list:
    """Segments whose creator is no longer running: left behind when a whole process group,
    resource tracker included, was killed with SIGKILL (a job scheduler, a closed container)."""
    return [n for n in leftover_segments(path)
            if (pid := segment_pid(n)) is not None and not _pid_alive(pid)]


def stale_bytes(path: str = SHM_DIR) -> int:
    """How much of ``path`` the stale segments hold."""
    return sum(file_size(os.path.join(path, n)) for n in stale_segments(path))


def file_size(file: str) -> int:
    try:
        return os.stat(file).st_size
    except FileNotFoundError:
        return 0
