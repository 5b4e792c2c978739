"""`posetrain study --engine ray`: each texture's run (dataset, training, evaluation) as a Ray task.

The driver (the `posetrain study` process) makes the textures, submits one task per texture and
writes the same report as a local study from what the tasks return. A task is
study.run_texture, the local study's own code, so it resumes the same way: a finished run is
not trained again, an unfinished one continues from its checkpoint.pth, the dataset from its
frames. The study folder must be the same path on every node (a shared filesystem).

Resources per task: `--run-cpus` CPUs (its training threads, its dataset's worker processes and
its preprocessing processes), plus one GPU when the run is on CUDA (`--device cuda`, or `auto`
on a cluster that has GPUs). A task whose worker or node dies is run again (it resumes).
"""
import time
from pathlib import Path

MAX_RETRIES = 2


def _task(tex, tdir, out, prof, cam, args, cpus):
    from .study import run_texture
    return run_texture(tex, Path(tdir), Path(out), prof, cam, args, workers=cpus)


def run_textures(textures, tdir, out, prof, cam, args):
    """{texture: (metrics, timings)} of every texture, each run as a Ray task."""
    import copy

    from sim.engine_ray import EngineError, connect
    cpus = max(1, args.run_cpus)
    with connect(args.ray_address, num_cpus=None, log_to_driver=True) as ray:
        gpus = ray.cluster_resources().get("GPU", 0)
        use_gpu = args.device.startswith("cuda") or (args.device == "auto" and gpus >= 1)
        if use_gpu and gpus < 1:
            raise EngineError(f"--device {args.device}: the Ray cluster has no GPU")
        task_args = copy.copy(args)
        # The task's own share of its node; on a GPU, the one Ray gives it (CUDA_VISIBLE_DEVICES).
        task_args.threads, task_args.workers, task_args.progress = cpus, cpus, False
        task_args.device = "cuda" if use_gpu else "cpu"
        remote = ray.remote(num_cpus=cpus, num_gpus=1 if use_gpu else 0, max_retries=MAX_RETRIES,
                            retry_exceptions=False)(_task)
        # Tasks run in other working directories, maybe on other nodes: absolute paths only.
        out, tdir = Path(out).resolve(), Path(tdir).resolve()
        cam = [str(Path(c).resolve()) if i and cam[i - 1] == "--camera" else c for i, c in enumerate(cam)]
        refs = {remote.remote(tex, str(tdir), str(out), prof, cam, task_args, cpus): tex for tex in textures}
        print(f"study: {len(refs)} runs as Ray tasks, {cpus} CPU{'s' if cpus > 1 else ''}"
              f"{' and 1 GPU' if use_gpu else ''} each", flush=True)
        done, t0 = {}, time.time()
        pending = list(refs)
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            tex = refs[ready[0]]
            try:
                done[tex] = ray.get(ready[0])
            except ray.exceptions.RayError as e:
                cause = getattr(e, "cause", None)
                why = f"{cause.__class__.__name__}: {cause}" if isinstance(cause, BaseException) else str(e)
                raise EngineError(f"study: {tex}: the run failed on the Ray cluster: {why}; the finished runs "
                                  f"are kept, rerun the same command to resume") from None
            print(f"study: {tex} done ({len(done)}/{len(refs)}, {time.time() - t0:.0f} s)", flush=True)
        return done
