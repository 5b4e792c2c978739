"""`sim dataset --engine ray`: the frames rendered as Ray tasks, on a cluster or on this machine.

The driver (the `sim dataset` process) plans the dataset, checks what is already on disk and
keeps the record exactly as the local engine does (sim/dataset.py); this module only renders
the missing frames. They are cut into shards of consecutive frames, one Ray task each:

- A task renders its frames with the same code as a local worker (sim.dataset._worker_init
  and _render_task, one renderer per worker process, made once and reused by later tasks of
  the same dataset), so a frame's bytes depend on the settings, the seed and its index only:
  the local engine, any worker count and any cluster give the same files.
- The task writes each frame itself, into the dataset folder, through a temporary file that
  is fsync'ed and renamed (sim.frames), so the folder must be the same path on every node (a
  shared filesystem). A frame written before a kill stays; a task killed half-way leaves
  temporaries that the next run removes.
- A task whose worker process or node dies is run again by Ray (max_retries); an exception
  inside a task (a bug, a full disk) fails the run with its message, as it would locally.
- At most a few shards per CPU are in flight at a time, so a million-frame plan does not
  become a million pending tasks, and the driver's progress bar advances shard by shard.

Connecting: an address (`--ray-address`, else RAY_ADDRESS) joins that cluster; without one a
private local instance is started for this run and stopped at its end (`address="local"`:
never a cluster that happens to run on this machine).
"""
import contextlib
import logging
import os

from sim.frames import remove_stale_temporaries

SHARD_MAX = 32          # frames per task at most: a task is then ~0.3-3 s, its scheduling ~1 ms
IN_FLIGHT_PER_CPU = 3   # shards submitted per cluster CPU: keeps every CPU busy without a huge queue
MAX_RETRIES = 3         # runs of a task whose worker or node died, after the first
COMMIT_THREADS = 2      # a task's threads that fsync and rename its frames while it renders the next


class EngineError(RuntimeError):
    """The cluster could not be reached, or a task failed for good; the message says which."""


@contextlib.contextmanager
def connect(address=None, num_cpus=None, log_to_driver=False):
    """Ray connected for the duration of the block: the cluster at `address` (or RAY_ADDRESS),
    else a private local instance with `num_cpus` CPUs that is shut down at the end.
    log_to_driver: the tasks' output on this process's stdout and stderr (off: the progress bar's)."""
    address = address or os.environ.get("RAY_ADDRESS") or None
    if address:
        _token_auth_if_token()      # before Ray is imported: it reads the mode once
    try:
        import ray
    except ImportError as e:
        raise EngineError(f"the Ray engine needs the ray package ({e}); `make deps` installs the version "
                          f"requirements.txt pins") from None
    kw = dict(logging_level=logging.WARNING, log_to_driver=log_to_driver, include_dashboard=False)
    if address:
        _check_reachable(address)
    try:
        if address:
            ray.init(address=address, **kw)
        else:
            # A small object store: tasks move only a few bytes (the settings and the frame list).
            ray.init(address="local", num_cpus=num_cpus, object_store_memory=256 << 20, **kw)
    except (ConnectionError, RuntimeError, ValueError) as e:
        where = f"the Ray cluster at {address}" if address else "a local Ray instance"
        raise EngineError(f"cannot start or reach {where}: {e}") from None
    try:
        yield ray
    finally:
        ray.shutdown()


def _check_reachable(address, timeout_s=10):
    """Fail at once, naming the address, when nothing listens there (Ray itself retries for minutes)."""
    import socket
    host, sep, port = address.rpartition(":")
    if not sep or not port.isdigit():
        raise EngineError(f"--ray-address {address}: expected HOST:PORT, the head's address (ray start --head "
                          f"prints it)")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout_s).close()
    except OSError as e:
        raise EngineError(f"no Ray cluster at {address} ({e.strerror or e}); start one with `ray start --head` "
                          f"(docs/cluster.md) or leave --ray-address and RAY_ADDRESS unset for a local "
                          f"instance") from None


def _token_auth_if_token():
    """Join with token authentication when a token is at hand and RAY_AUTH_MODE does not say.

    `ray start` enables token authentication by itself when it finds a token (~/.ray/auth_token,
    RAY_AUTH_TOKEN, RAY_AUTH_TOKEN_PATH) but a process joining a cluster does not; without this, a
    head started with a token refuses the run ("Authentication token is missing or incorrect")."""
    if "RAY_AUTH_MODE" in os.environ:
        return
    if (os.environ.get("RAY_AUTH_TOKEN") or os.environ.get("RAY_AUTH_TOKEN_PATH")
            or os.path.exists(os.path.expanduser("~/.ray/auth_token"))):
        os.environ["RAY_AUTH_MODE"] = "token"


def cluster_cpus(ray):
    return max(1, int(ray.cluster_resources().get("CPU", 1)))


def shards(tasks, cpus):
    """Consecutive runs of the (index, path, pose) tasks: enough shards for 4 per CPU, at most
    SHARD_MAX frames each."""
    size = max(1, min(SHARD_MAX, -(-len(tasks) // (4 * cpus))))
    return [tasks[i:i + size] for i in range(0, len(tasks), size)]


# ---- the task (runs in a Ray worker process) ---------------------------------

_LOADED = {"key": None}


def render_shard(cfg, key, shard):
    """Render and commit the frames of `shard` ((index, path, pose) each); returns how many.

    `key` names the dataset's settings: a worker keeps its renderer across tasks of one key."""
    from concurrent.futures import ThreadPoolExecutor

    from sim import dataset
    from sim.frames import commit_temporary
    if _LOADED["key"] != key:
        dataset._worker_init(cfg, single_thread_gl=True)
        _LOADED["key"] = key
    with ThreadPoolExecutor(COMMIT_THREADS) as committer:
        commits = [committer.submit(commit_temporary, *dataset._render_task(task)) for task in shard]
        for c in commits:
            c.result()
    return len(shard)


# ---- the driver --------------------------------------------------------------

def render(cfg, tasks, key, *, address=None, workers=None, on_frames=None, log=print):
    """Render `tasks` ((index, absolute path, pose)) on Ray; on_frames(n) after each finished shard.

    workers: without an address, the CPUs of the local instance this starts (0/None: every core
    here); on a cluster, at most this many tasks at a time (0/None: as many as it has CPUs, with a
    few more queued). Returns the CPUs used."""
    address = address or os.environ.get("RAY_ADDRESS") or None
    with connect(address, num_cpus=workers or None) as ray:
        cpus = cluster_cpus(ray)
        limit = IN_FLIGHT_PER_CPU * cpus
        if workers and address:     # a share of a cluster: exactly `workers` tasks at a time
            cpus = limit = min(cpus, workers)
        log(f"ray: {len(tasks)} frames on {cpus} CPUs" + (f" of the cluster at {address}" if address else ""))
        remote = ray.remote(num_cpus=1, max_retries=MAX_RETRIES, retry_exceptions=False)(render_shard)
        cfg_ref = ray.put(cfg)
        pending = list(reversed(shards(tasks, cpus)))
        running = {}
        while pending or running:
            while pending and len(running) < limit:
                shard = pending.pop()
                running[remote.remote(cfg_ref, key, shard)] = shard
            done, _ = ray.wait(list(running), num_returns=1)
            for ref in done:
                shard = running.pop(ref)
                try:
                    n = ray.get(ref)
                except ray.exceptions.RayError as e:
                    first, last = shard[0][0], shard[-1][0]
                    raise EngineError(f"frames {first}-{last} ({os.path.basename(shard[0][1])} ...) failed on "
                                      f"the Ray cluster: {_reason(e)}") from None
                if on_frames:
                    on_frames(n)
    # A task killed half-way and run again left its temporaries; every task is done, so none is in use.
    for folder in sorted({os.path.dirname(path) for _, path, _ in tasks}):
        remove_stale_temporaries(folder)
    return cpus


def _reason(e):
    """The useful part of a Ray error: the task's own exception, else Ray's first line."""
    cause = getattr(e, "cause", None)
    if isinstance(cause, BaseException):
        return f"{cause.__class__.__name__}: {cause}"
    return str(e).strip().splitlines()[0] if str(e).strip() else e.__class__.__name__
