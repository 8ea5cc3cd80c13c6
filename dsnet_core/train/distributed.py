"""Data-parallel training across processes launched by ``torchrun`` (one process per GPU).

:func:`setup` reads torchrun's environment (``WORLD_SIZE``, ``RANK``, ``LOCAL_RANK``) and starts the
process group (NCCL for CUDA, gloo for CPU); a process started without torchrun, or with one
process, gets a :class:`Distributed` of one rank whose collectives do nothing, so the trainer has a
single code path. :func:`shard` is the distributed sampler: an epoch's order, identical on every
rank, padded by repetition and dealt out round robin so that every rank takes the same number of
steps.

Batch norm stays per process (no ``SyncBatchNorm``: it needs CUDA): each rank normalises its own
volumes, and ``DistributedDataParallel`` broadcasts rank 0's running statistics before every
training forward pass, so rank 0's statistics are the model's. :meth:`Distributed.sync_buffers`
copies them to every rank before the model is used in eval mode.
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

import numpy as np
import torch
import torch.distributed as dist
from torch import nn

T = TypeVar("T")


@dataclass(frozen=True)
class Distributed:
    """This process's place among the training processes.

    Attributes:
        rank: global rank (0 writes the checkpoint).
        world_size: number of processes (1 = no data parallelism, every collective a no-op).
        local_rank: rank on this machine (the CUDA device index).
    """

    rank: int = 0
    world_size: int = 1
    local_rank: int = 0

    @property
    def active(self) -> bool:
        return self.world_size > 1

    @property
    def is_main(self) -> bool:
        """The process that writes files and reports progress."""
        return self.rank == 0

    def barrier(self) -> None:
        """Wait for every rank (after rank 0 wrote files that the others read next)."""
        if self.active:
            dist.barrier()

    def from_main(self, fn: Callable[[], T]) -> T:
        """Run ``fn`` on rank 0 only (reads or writes that must happen once) and hand its result
        to every rank; the other ranks wait meanwhile."""
        box = [fn() if self.is_main else None]
        if self.active:
            dist.broadcast_object_list(box, src=0)
        return box[0]

    def all_gather(self, obj: T) -> list[T]:
        """Every rank's ``obj`` (picklable), in rank order, on every rank."""
        if not self.active:
            return [obj]
        out: list = [None] * self.world_size
        dist.all_gather_object(out, obj)
        return out

    def part(self, n: int) -> range:
        """This rank's contiguous part of ``range(n)`` (sizes differ by at most one); the parts in
        rank order are ``range(n)`` in order, so per-item results gathered in rank order are in
        item order (validation sums in the single-process order)."""
        return range(n * self.rank // self.world_size, n * (self.rank + 1) // self.world_size)

    def wrap(self, module: nn.Module, device: torch.device) -> nn.Module:
        """``module`` in :class:`DistributedDataParallel` (gradients averaged over ranks), or itself
        with one rank. Wrap after choosing the trainable parameters: DDP averages those that have
        ``requires_grad`` when it is built, and every one of them must get a gradient each step."""
        if not self.active:
            return module
        ids = [device.index] if device.type == "cuda" else None
        # DDP's default: rank 0's buffers (batch-norm statistics) are broadcast before every forward
        return nn.parallel.DistributedDataParallel(module, device_ids=ids)

    def sync_buffers(self, module: nn.Module) -> None:
        """Copy rank 0's buffers (batch-norm running statistics) to every rank."""
        if self.active:
            for buf in module.buffers():
                dist.broadcast(buf, src=0)


def setup(device: str) -> tuple[Distributed, torch.device]:
    """Join the training processes that torchrun started, if any.

    Args:
        device: ``"cpu"`` or ``"cuda"``; under torchrun a CUDA rank takes ``cuda:LOCAL_RANK``.

    Returns:
        (this process's :class:`Distributed`, its device). The process group is started once
        (NCCL for CUDA, gloo for CPU) and reused when already started.
    """
    world = int(os.environ.get("WORLD_SIZE", "1"))
    dev = torch.device(device)
    if world <= 1:
        return Distributed(), dev
    rank, local = int(os.environ["RANK"]), int(os.environ.get("LOCAL_RANK", "0"))
    if dev.type == "cuda":
        dev = torch.device("cuda", local)
        torch.cuda.set_device(dev)
    if not dist.is_initialized():
        if dev.type == "cuda":
            dist.init_process_group("nccl", device_id=dev)
        else:
            dist.init_process_group("gloo")
    return Distributed(rank=rank, world_size=world, local_rank=local), dev


def teardown() -> None:
    """End the process group (at the end of a torchrun process; nothing without one)."""
    if dist.is_available() and dist.is_initialized():
        dist.destroy_process_group()


def shard(order: np.ndarray, world_size: int, rank: int) -> np.ndarray:
    """One rank's share of an epoch (the distributed sampler).

    ``order`` (the epoch's shuffled volume indices, identical on every rank) is padded to a
    multiple of ``world_size`` by repeating it from its start, as ``DistributedSampler`` does, and
    dealt out round robin: rank ``r`` takes positions ``r, r + W, r + 2W, …``. Every rank gets
    ``ceil(n / W)`` indices, so all take the same number of steps, and step ``s`` of all ranks
    together (batch ``b`` each) covers positions ``s·b·W … (s+1)·b·W − 1`` of the padded order: the
    volumes one process with batch ``b·W`` would take at step ``s``.

    Args:
        order: int ``(n,)`` the epoch's order.
        world_size, rank: the processes and this one.

    Returns:
        int ``(ceil(n / world_size),)``.
    """
    n = len(order)
    total = -(-n // world_size) * world_size
    return np.resize(np.asarray(order), total)[rank::world_size]
