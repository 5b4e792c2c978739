"""`posetrain train` under torchrun: DistributedDataParallel over the processes torchrun starts.

    torchrun --nproc-per-node 2 --no-python posetrain train --data DIR --out DIR ...

torchrun sets WORLD_SIZE, RANK, LOCAL_RANK and LOCAL_WORLD_SIZE; with WORLD_SIZE > 1 a run:

- joins the process group: NCCL when the run is on CUDA (process k on GPU LOCAL_RANK), gloo on CPU;
- keeps the recipe of the command: `--batch-size` stays the batch of one optimiser step, split
  evenly over the processes, so the steps per epoch, the learning-rate schedule and the
  gradient (DDP averages equal shares) are those of one process;
- deals each epoch's frames with a DistributedSampler (seeded by --seed and the epoch, so a
  resumed run deals the same), each process its share;
- draws its augmentation from a generator of (seed, rank, epoch), again the same after a resume;
- lets rank 0 alone evaluate, log, write checkpoints, the report and the ONNX file; the others
  wait for it at the next step;
- with --threads 0 uses this node's cores divided by its processes.

Without torchrun (or with one process) none of this runs: a run is exactly the single-process one.
"""
import contextlib
import datetime
import os
from dataclasses import dataclass

import numpy as np
import torch
import torch.distributed as dist

# Rank 0 evaluates and writes files while the others wait in the next collective: long enough
# for a validation pass on a CPU, short enough that a hung process is noticed.
TIMEOUT = datetime.timedelta(minutes=60)


@dataclass(frozen=True)
class Context:
    world: int = 1
    rank: int = 0
    local_rank: int = 0
    local_world: int = 1

    @property
    def active(self):
        return self.world > 1

    @property
    def main(self):
        return self.rank == 0


SINGLE = Context()


def from_env():
    """The Context torchrun's variables describe (SINGLE without them)."""
    def num(name, default):
        value = os.environ.get(name, "")
        try:
            return int(value) if value else default
        except ValueError:
            raise ValueError(f"environment variable {name}={value!r} is not a whole number "
                             f"(set by torchrun; unset it to train in one process)") from None
    world = num("WORLD_SIZE", 1)
    return Context(world, num("RANK", 0), num("LOCAL_RANK", 0), num("LOCAL_WORLD_SIZE", world))


def setup(device_name, batch_size):
    """Join the process group; returns (Context, torch.device) for this process.

    device_name: posetrain's --device (auto, cpu, cuda, cuda:N; under torchrun a GPU run takes
    cuda:LOCAL_RANK whatever N)."""
    ctx = from_env()
    if batch_size % ctx.world:
        raise ValueError(f"--batch-size {batch_size} is the batch of one step over all {ctx.world} processes: "
                         f"it must be a multiple of {ctx.world}")
    want_cuda = device_name == "auto" and torch.cuda.is_available() or device_name.startswith("cuda")
    if want_cuda and not torch.cuda.is_available():
        raise SystemExit(f"posetrain: device {device_name!r} requested but CUDA is not available; valid here: auto, cpu")
    if want_cuda:
        device = torch.device("cuda", ctx.local_rank)
        torch.cuda.set_device(device)
    else:
        device = torch.device("cpu")
    dist.init_process_group("nccl" if want_cuda else "gloo", timeout=TIMEOUT)
    return ctx, device


def finish(ctx):
    if ctx.active and dist.is_initialized():
        dist.destroy_process_group()


def threads(n, ctx):
    """torch threads of this process: n, or (n = 0) this node's cores shared among its processes."""
    return n if n > 0 else max(1, (os.cpu_count() or 1) // ctx.local_world)


@contextlib.contextmanager
def main_first(ctx):
    """Rank 0 runs the block first (it builds the preprocessed-frame caches), then the others
    (they read them): never two processes writing one cache."""
    if ctx.active and not ctx.main:
        dist.barrier()
    yield
    if ctx.active and ctx.main:
        dist.barrier()


def wrap(model, ctx, device):
    from torch.nn.parallel import DistributedDataParallel
    return DistributedDataParallel(model, device_ids=[device.index] if device.type == "cuda" else None)


class ShardBatches:
    """This process's batches of one epoch: a DistributedSampler's share, in batches of
    batch_size / world (the last incomplete one dropped, as a single process drops it)."""

    def __init__(self, data, batch_size, ctx, seed, epoch):
        from torch.utils.data import DistributedSampler
        sampler = DistributedSampler(range(len(data)), num_replicas=ctx.world, rank=ctx.rank, shuffle=True,
                                     seed=seed, drop_last=True)
        sampler.set_epoch(epoch)
        self.data, self.order = data, torch.tensor(list(sampler), dtype=torch.long)
        self.size = batch_size // ctx.world
        n = len(self.order)
        self.stop = n - n % self.size if n >= self.size else n

    def __len__(self):
        return -(-self.stop // self.size)

    def __iter__(self):
        for i in range(0, self.stop, self.size):
            idx = self.order[i:i + self.size]
            yield self.data.images[idx], self.data.labels[idx]


def generator(seed, ctx, epoch):
    """The augmentation generator of one process and epoch."""
    state = np.random.SeedSequence([seed, ctx.rank, epoch]).generate_state(2, np.uint64)
    return torch.Generator().manual_seed(int(state[0] >> np.uint64(1)))


def _collective(t):
    """`t` where the process group's backend can reduce it (NCCL: on this process's GPU)."""
    return t.cuda() if dist.get_backend() == "nccl" else t


def agree(flag, ctx):
    """True on every process when it is true on any (a time budget spent somewhere stops all
    at the same step: a process that stopped alone would leave the others waiting)."""
    if not ctx.active:
        return bool(flag)
    t = _collective(torch.tensor([1 if flag else 0], dtype=torch.int32))
    dist.all_reduce(t, op=dist.ReduceOp.MAX)
    return bool(t.item())


def average(values, ctx):
    """The mean over processes of each value (equal shares: the mean of the whole batch)."""
    if not ctx.active:
        return list(values)
    t = _collective(torch.tensor([float(v) for v in values], dtype=torch.float64))
    dist.all_reduce(t, op=dist.ReduceOp.SUM)
    return [float(v) / ctx.world for v in t.cpu()]
