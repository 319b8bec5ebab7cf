#!/usr/bin/env python3
"""Runs the tile jobs of a rogs plan on a Ray cluster, then merges them into the map.

    rogs plan drive.zip --out PLAN/ --tile-m 64            # the jobs
    python3 scripts/ray_map.py PLAN/ --tiles TILES/ --out MAP/ [--address ADDR]

One Ray task per tile runs the native `rogs reconstruct --plan PLAN --tile NAME --out
TILES/NAME`; a final task runs `rogs merge PLAN TILES --out MAP`. PLAN, TILES, MAP and
the bundles the plan names must be paths every worker sees (shared storage; a local
folder on one machine). docs/DISTRIBUTED.md says how to run it on GPUs and Kubernetes.

- Resume: a tile whose checkpoint (TILES/NAME/NAME.tile) is sound is not run again. A
  checkpoint is sound when every zip entry inflates with its CRC-32 and its tile.json
  names the plan's fingerprint and the tile; a damaged one is run again (rogs checks
  the same before it skips a job).
- Retries: a task whose worker dies (killed, out of memory, node lost) is retried by
  Ray (--retries); one whose rogs stops because of the machine (exit code 4, a lost
  device) is retried too; bad input (exit code 3) is not: it would fail again.
- Progress: one line per finished tile with the time it took and an ETA.

Without --address a local cluster is started with --workers worker processes.
Exit codes: 0 the map is written, 3 bad input (the plan, a bundle), 4 a tile or the
merge failed after its retries.
"""

import argparse
import ctypes
import json
import os
import shutil
import signal
import subprocess
import sys
import time
import zipfile

EXIT_INVALID_INPUT = 3
EXIT_MACHINE = 4


class InputError(Exception):
    """rogs refused its input (exit code 3): running it again would not help."""


class MachineError(Exception):
    """rogs stopped because of the machine (exit code 4 or a signal): worth a retry."""


def checkpoint_problem(path, plan, index):
    """None when `path` is a sound checkpoint of tile `index` of `plan`, else why not."""
    try:
        with zipfile.ZipFile(path) as z:
            bad = z.testzip()
            if bad is not None:
                return f"entry {bad} fails its CRC-32"
            head = json.loads(z.read("tile.json"))
    except FileNotFoundError:
        return "missing"
    except (zipfile.BadZipFile, KeyError, ValueError, OSError) as e:
        return f"not a tile checkpoint ({e})"
    if head.get("fingerprint") != plan["fingerprint"]:
        return f"made by another run (fingerprint {head.get('fingerprint')}, the plan's is {plan['fingerprint']})"
    if head.get("index") != index:
        return f"it is tile {head.get('index')} of its plan, not {index}"
    return None


def die_with_parent():
    """In the child: die when the worker that started it dies (Linux)."""
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except OSError:
        pass


def run_rogs(args, log_path):
    """Runs rogs with `args`; its stderr goes to `log_path` (appended)."""
    with open(log_path, "ab") as log:
        log.write(f"\n== pid {os.getpid()} at {time.strftime('%H:%M:%S')}: rogs {' '.join(args[1:])}\n".encode())
        log.flush()
        p = subprocess.run(args, stdout=log, stderr=log, preexec_fn=die_with_parent)
    if p.returncode == 0:
        return
    tail = open(log_path, "rb").read()[-1500:].decode("utf-8", "replace")
    msg = f"rogs {args[1]} exited with {p.returncode}; the end of {log_path}:\n{tail}"
    if p.returncode == EXIT_INVALID_INPUT:
        raise InputError(msg)
    raise MachineError(msg)


def tile_task(rogs, plan_dir, tiles_dir, name):
    """One tile job (a Ray task's body). Returns the job's job.json."""
    out = os.path.join(tiles_dir, name)
    os.makedirs(out, exist_ok=True)
    # Each attempt leaves a line: the tests count them to see a retry.
    with open(os.path.join(out, "attempts"), "a") as f:
        f.write(f"{os.getpid()} {time.time():.3f}\n")
    t0 = time.time()
    try:
        run_rogs([rogs, "reconstruct", "--plan", plan_dir, "--tile", name, "--out", out], os.path.join(out, "rogs.log"))
    except InputError as e:
        # Returned, not raised: Ray retries what is raised.
        return {"input_error": str(e)}
    try:
        with open(os.path.join(out, "job.json")) as f:
            job = json.load(f)
    except (OSError, ValueError):
        job = {}
    job["task_seconds"] = time.time() - t0
    return job


def merge_task(rogs, plan_dir, tiles_dir, out, extra):
    os.makedirs(out, exist_ok=True)
    t0 = time.time()
    try:
        run_rogs([rogs, "merge", plan_dir, tiles_dir, "--out", out] + extra, os.path.join(out, "merge.log"))
    except InputError as e:
        return {"input_error": str(e)}
    return {"seconds": time.time() - t0}


def find_rogs(given):
    if given:
        return os.path.abspath(given)
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    for p in ("target/release/rogs", "target/debug/rogs"):
        if os.access(os.path.join(here, p), os.X_OK):
            return os.path.join(here, p)
    return shutil.which("rogs")


def main(argv=None):
    ap = argparse.ArgumentParser(
        description="Run a rogs plan's tile jobs on a Ray cluster and merge them into the map.",
        epilog="Make the plan with `rogs plan BUNDLE… --out PLAN`. docs/DISTRIBUTED.md.",
    )
    ap.add_argument("plan", help="the plan's folder (plan.json, jobs/)")
    ap.add_argument("--tiles", required=True, help="folder of the tile outputs (TILES/NAME/NAME.tile); kept for resume")
    ap.add_argument("--out", required=True, help="folder of the merged map")
    ap.add_argument("--address", help="a running cluster (ray://HOST:10001 or HOST:6379); default: start a local one")
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1, help="CPUs of the local cluster (default: this machine's)")
    ap.add_argument("--cpus-per-tile", type=float, default=1.0, help="CPUs a tile task reserves (default 1)")
    ap.add_argument("--gpus-per-tile", type=float, default=0.0, help="GPUs a tile task reserves (default 0; with ROGS_REAL_GPU=1 set 1)")
    ap.add_argument("--retries", type=int, default=3, help="retries of a tile whose worker or machine failed (default 3)")
    ap.add_argument("--rogs", help="the rogs binary, at a path every worker sees (default: this checkout's target/release or target/debug, else PATH)")
    ap.add_argument("--ply-up", choices=["z", "y"], default="z", help="up axis of the merged PLY files")
    a = ap.parse_args(argv)

    plan_dir, tiles_dir, out = (os.path.abspath(p) for p in (a.plan, a.tiles, a.out))
    try:
        with open(os.path.join(plan_dir, "plan.json")) as f:
            plan = json.load(f)
        jobs = plan["jobs"]
        plan["fingerprint"]
    except (OSError, ValueError, KeyError) as e:
        print(f"{plan_dir}/plan.json: {e} (make the plan with `rogs plan BUNDLE… --out PLAN`)", file=sys.stderr)
        return EXIT_INVALID_INPUT
    rogs = find_rogs(a.rogs)
    if not rogs:
        print("no rogs binary: build it (cargo build --release) or pass --rogs PATH", file=sys.stderr)
        return EXIT_INVALID_INPUT

    todo = []
    for j in jobs:
        ckpt = os.path.join(tiles_dir, j["tile"], j["tile"] + ".tile")
        problem = checkpoint_problem(ckpt, plan, j["index"])
        if problem is None:
            continue
        if problem != "missing":
            print(f"{ckpt}: {problem}: running tile {j['tile']} again", file=sys.stderr)
        todo.append(j)
    done = len(jobs) - len(todo)
    print(f"{len(jobs)} tiles: {done} already finished, {len(todo)} to run", file=sys.stderr)

    import ray  # after the checks: a bad plan is told at once

    # The environment rogs needs on every worker (Vulkan driver choice, real GPU).
    keep = ("ROGS_REAL_GPU", "WGPU_BACKEND", "VK_ICD_FILENAMES", "XDG_RUNTIME_DIR", "RUST_LOG")
    env = {k: os.environ[k] for k in keep if k in os.environ}
    runtime_env = {"env_vars": env} if env else None
    if a.address:
        ray.init(address=a.address, runtime_env=runtime_env, log_to_driver=False)
    else:
        ray.init(
            num_cpus=a.workers,
            num_gpus=1 if a.gpus_per_tile > 0 else 0,
            include_dashboard=False,
            object_store_memory=100 * 1024 * 1024,
            runtime_env=runtime_env,
            log_to_driver=False,
        )
    tile = ray.remote(
        num_cpus=a.cpus_per_tile,
        num_gpus=a.gpus_per_tile,
        max_retries=a.retries,
        retry_exceptions=True,
    )(tile_task)
    merge = ray.remote(num_cpus=1, max_retries=a.retries, retry_exceptions=True)(merge_task)

    t0 = time.time()
    pending = {tile.remote(rogs, plan_dir, tiles_dir, j["tile"]): j for j in todo}
    steps_left = sum(j["steps"] for j in todo) or 1
    steps_done, failed, per_tile = 0, [], []
    while pending:
        ready, _ = ray.wait(list(pending), num_returns=1)
        j = pending.pop(ready[0])
        try:
            job = ray.get(ready[0])
        except Exception as e:  # the task's last attempt failed
            cause = getattr(e, "cause", None) or e
            failed.append((j["tile"], False))
            print(f"tile {j['tile']} failed: {cause}", file=sys.stderr)
            continue
        if "input_error" in job:
            failed.append((j["tile"], True))
            print(f"tile {j['tile']} failed: {job['input_error']}", file=sys.stderr)
            continue
        done += 1
        steps_done += j["steps"]
        per_tile.append({"tile": j["tile"], "seconds": job.get("seconds"), "task_seconds": job.get("task_seconds")})
        spent = time.time() - t0
        eta = spent / max(steps_done, 1) * (steps_left - steps_done)
        print(
            f"[{done}/{len(jobs)}] tile {j['tile']} in {job.get('task_seconds', 0):.1f} s, ETA {eta:.0f} s",
            file=sys.stderr,
        )
    tiles_s = time.time() - t0
    if failed:
        names = ", ".join(t for t, _ in failed)
        kind = "bad input" if any(bad for _, bad in failed) else "the machine"
        print(f"{len(failed)} tiles failed ({kind}): {names}; the finished ones are kept in {tiles_dir}: run again to resume", file=sys.stderr)
        ray.shutdown()
        return EXIT_INVALID_INPUT if kind == "bad input" else EXIT_MACHINE
    try:
        merged = ray.get(merge.remote(rogs, plan_dir, tiles_dir, out, ["--ply-up", a.ply_up]))
    except Exception as e:
        merged = {"machine_error": str(getattr(e, "cause", None) or e)}
    ray.shutdown()
    if "seconds" not in merged:
        print(f"the merge failed: {merged}", file=sys.stderr)
        return EXIT_INVALID_INPUT if "input_error" in merged else EXIT_MACHINE
    merge_s = merged["seconds"]
    summary = {"tiles": len(jobs), "ran": len(todo), "tiles_seconds": tiles_s, "merge_seconds": merge_s, "per_tile": per_tile}
    with open(os.path.join(out, "ray.json"), "w") as f:
        json.dump(summary, f, indent=2)
    print(f"map written to {out}: {len(todo)} tiles run in {tiles_s:.1f} s, merge {merge_s:.1f} s", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
