"""`--executor ray`: every run a Ray task on a cluster's workers.

Each task runs `eurocslam run` + eval on its worker (the same `task.execute` as local runs) and
returns the run's record. Where outputs go:

* `shared`: OUT is on a filesystem every node sees at the same path; workers write into it.
* `fetch`: workers write into their cache folder and return the files, written into OUT here.
* `auto` (default): `shared` when every node sees OUT (a probe file written here), else `fetch`.

Sequences must be readable on the workers: a folder at the same path on every node (a shared
filesystem), or a synth spec, rendered on each worker's machine (once per machine, cached).
Before any run starts, a check task on every node verifies that: the same eurocslam code, every
sequence folder and synth input readable, and whether OUT is visible; a problem is a one-line
error naming the node and the path.

A worker that dies (killed, out of memory, node lost) fails its run (tasks are not retried);
Ctrl-C cancels the tasks not finished (their run processes are stopped) and keeps the others.

Ray is an optional dependency (`pip install 'eurocslam[ray]'`), imported only here.
"""

from __future__ import annotations

import contextlib
import logging
import shutil
import socket
import tempfile
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

from eurocslam.errors import ConfigError
from eurocslam.eval.bench.plan import SYNTH_PATH_KEYS
from eurocslam.eval.bench.sequences import check_sequence_folder, ensure_synth, synth_cache_name
from eurocslam.eval.bench.task import (
    RunRecord,
    RunTask,
    execute,
    package_digest,
    worker_identity,
    write_record,
)

logger = logging.getLogger(__name__)

INSTALL_HINT = (
    "--executor ray needs Ray, an optional extra of eurocslam: pip install 'eurocslam[ray]' "
    "(in a source checkout: pip install -e '.[ray]')"
)
CHECK_TIMEOUT_S = 120.0
CONNECT_TIMEOUT_S = 5.0
CANCEL_GRACE_S = 10.0
OUTPUT_MODES = ("auto", "shared", "fetch")


def _import_ray() -> Any:
    try:
        import ray
    except ImportError:
        raise ConfigError(INSTALL_HINT) from None
    return ray


def default_cache() -> Path:
    return Path(tempfile.gettempdir()) / "eurocslam_bench"


def _node_identity() -> dict[str, Any]:
    import ray

    ctx = ray.get_runtime_context()
    who = worker_identity("ray")
    who["node_id"] = ctx.get_node_id()
    who["node_ip"] = ray.util.get_node_ip_address()  # type: ignore[no-untyped-call]
    who["worker_id"] = ctx.get_worker_id()
    return who


# ---- worker side -------------------------------------------------------------------------


def check_node(
    folders: dict[str, str], synth_inputs: dict[str, list[str]], probe: tuple[str, str] | None
) -> dict[str, Any]:
    """On one node: what it runs and what it cannot see (the pre-flight check)."""
    problems: list[str] = []
    for name, path in folders.items():
        why = check_sequence_folder(name, Path(path))
        if why:
            problems.append(f"cannot read sequence '{name}': {why}")
    for name, files in synth_inputs.items():
        for f in files:
            if not Path(f).exists():
                problems.append(f"cannot read synth input {f} of sequence '{name}'")
    seen = False
    if probe is not None:
        try:
            seen = Path(probe[0]).read_text() == probe[1]
        except OSError:
            seen = False
    pkg, digest = package_digest()
    return {
        **_node_identity(),
        "package": pkg,
        "digest": digest,
        "problems": problems,
        "sees_out": seen,
    }


def run_task(task: RunTask, mode: str, cache: str | None) -> tuple[dict[str, Any], Any]:
    """On a worker: the run and its evaluation; (record, None) in `shared` mode, (record,
    {relative path: bytes}) in `fetch` mode."""
    root = Path(cache) if cache else default_cache()
    who = _node_identity()
    if task.seq_path is not None:
        seq = task.seq_path
    else:
        assert task.synth is not None
        dest = root / "sequences" / synth_cache_name(task.sequence, task.synth)
        seq = ensure_synth(task.sequence, task.synth, dest, progress=False)
    if mode == "shared":
        return execute(task, seq, task.out_dir, who).to_dict(), None
    (root / "runs").mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=root / "runs"))
    run = tmp / task.out_dir.name  # the same folder name as in OUT (run_K)
    try:
        rec = execute(task, seq, run, who)
        if rec.error:  # name the folder the files end up in
            rec.error = rec.error.replace(str(run), str(task.out_dir))
        rec.command = [c.replace(str(run), str(task.out_dir)) for c in rec.command]
        files = {
            p.relative_to(run).as_posix(): p.read_bytes() for p in run.rglob("*") if p.is_file()
        }
        return rec.to_dict(), files
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


# ---- driver side -------------------------------------------------------------------------


def _head_address(address: str) -> tuple[str, int] | None:
    """The head's GCS (host, port) as ray.init will resolve `address` ('auto': the cluster this
    machine belongs to); None when that cannot be told (e.g. a ray:// client address)."""
    if address.startswith("ray://"):
        return None
    try:
        from ray._private.services import canonicalize_bootstrap_address_or_die
    except ImportError:  # pragma: no cover - a Ray without it: ray.init alone
        return None
    try:
        hostport = canonicalize_bootstrap_address_or_die(address)
    except (ConnectionError, ValueError) as e:
        raise ConfigError(f"Ray cluster {address!r}: {' '.join(str(e).split())}") from None
    host, _, port = hostport.rpartition(":")
    return host.strip("[]"), int(port)


def _connect(ray: Any, address: str) -> None:
    """ray.init, after a bounded check that the head answers (ray.init itself retries an
    unreachable head for ever)."""
    head = _head_address(address)
    if head is not None:
        try:
            socket.create_connection(head, timeout=CONNECT_TIMEOUT_S).close()
        except OSError as e:
            raise ConfigError(
                f"cannot reach the Ray head at {address} ({head[0]}:{head[1]}): "
                f"{e.strerror or e}; start one with `ray start --head --port PORT`, or give "
                "the address of a running one"
            ) from None
    try:
        ray.init(address=address, log_to_driver=False, logging_level=logging.WARNING)
    except (ConnectionError, RuntimeError, ValueError) as e:
        raise ConfigError(
            f"cannot connect to the Ray cluster at {address}: {' '.join(str(e).split())}"
        ) from None


def _preflight(ray: Any, tasks: list[RunTask], out_dir: Path, mode: str) -> str:
    """Check every node before any run; returns the output mode to use (shared or fetch)."""
    from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

    nodes = [n for n in ray.nodes() if n.get("Alive") and n.get("Resources", {}).get("CPU", 0) > 0]
    if not nodes:
        raise ConfigError("the Ray cluster has no alive node with CPUs")
    folders = {t.sequence: str(t.seq_path) for t in tasks if t.seq_path is not None}
    synth_inputs = {
        t.sequence: [str(t.synth[k]) for k in SYNTH_PATH_KEYS if t.synth.get(k)]
        for t in tasks
        if t.synth is not None
    }
    probe_file = out_dir / f".bench_probe_{uuid.uuid4().hex}"
    token = uuid.uuid4().hex
    probe_file.write_text(token)
    check = ray.remote(check_node)
    refs = {
        check.options(
            num_cpus=0,
            max_retries=0,
            scheduling_strategy=NodeAffinitySchedulingStrategy(n["NodeID"], soft=False),
        ).remote(folders, synth_inputs, (str(probe_file), token)): n
        for n in nodes
    }
    _, here = package_digest()
    sees_out = True
    try:
        ready, not_ready = ray.wait(list(refs), num_returns=len(refs), timeout=CHECK_TIMEOUT_S)
        if not_ready:
            n = refs[not_ready[0]]
            raise ConfigError(
                f"Ray node {n['NodeManagerAddress']} did not answer the check before the bench "
                f"within {CHECK_TIMEOUT_S:.0f} s"
            )
        for ref in ready:
            n = refs[ref]
            try:
                r = ray.get(ref)
            except ray.exceptions.RayError as e:
                raise ConfigError(
                    f"Ray node {n['NodeManagerAddress']} cannot run eurocslam's bench task "
                    f"({_one_line(e)}); install the same eurocslam on every node "
                    "(pip install 'eurocslam[ray]')"
                ) from None
            where = f"Ray node {r['node_ip']} ({r['host']})"
            if r["digest"] != here:
                raise ConfigError(
                    f"{where} runs other eurocslam code ({r['package']}) than this machine: "
                    "install the same eurocslam on every node"
                )
            if r["problems"]:
                raise ConfigError(
                    f"{where} {r['problems'][0]}: Ray workers read sequence folders at the same "
                    "path as this machine (a shared filesystem), or give the sequence as a "
                    "synth spec to render it on the workers"
                )
            if not r["sees_out"]:
                sees_out = False
                if mode == "shared":
                    raise ConfigError(
                        f"--ray-outputs shared: {where} does not see {out_dir} (this machine's "
                        "output folder): give an OUT on a shared filesystem, or --ray-outputs fetch"
                    )
    finally:
        probe_file.unlink(missing_ok=True)
    if mode == "auto":
        mode = "shared" if sees_out else "fetch"
    logger.info(
        f"eurocslam bench: Ray cluster with {len(nodes)} node(s); outputs "
        + (
            "written by the workers into OUT (shared)"
            if mode == "shared"
            else "brought back into OUT"
        )
    )
    return mode


def _one_line(e: BaseException) -> str:
    lines = [ln.strip() for ln in str(e).splitlines() if ln.strip()]
    return lines[-1] if lines else type(e).__name__


def _failed(task: RunTask, e: BaseException) -> RunRecord:
    kind = type(e).__name__
    why = (
        "the Ray worker died" if "Crash" in kind or "Died" in kind else f"Ray task failed ({kind})"
    )
    return RunRecord(
        task.sequence,
        task.index,
        task.out_dir,
        task.config,
        error=f"{why}: {_one_line(e)}",
        worker={"executor": "ray"},
        fingerprint=task.fingerprint(),
    )


def _materialize(task: RunTask, rec_d: dict[str, Any], files: dict[str, bytes] | None) -> RunRecord:
    rec = RunRecord.from_dict(rec_d)
    if files is not None:  # fetch mode: the worker's files into OUT
        shutil.rmtree(task.out_dir, ignore_errors=True)
        for rel, data in files.items():
            dest = task.out_dir / rel
            dest.parent.mkdir(parents=True, exist_ok=True)
            dest.write_bytes(data)
        rec.out_dir = task.out_dir
        if rec.ok:
            write_record(rec)
    return rec


def run_ray(
    tasks: list[RunTask],
    out_dir: Path,
    on_done: Callable[[RunRecord], None],
    *,
    address: str = "auto",
    cpus_per_run: float = 2.0,
    outputs: str = "auto",
    worker_cache: str | None = None,
) -> None:
    """Run the tasks as Ray tasks; `on_done` as each finishes. Ctrl-C: KeyboardInterrupt after
    the unfinished tasks are cancelled."""
    if outputs not in OUTPUT_MODES:
        raise ConfigError(f"--ray-outputs must be one of {', '.join(OUTPUT_MODES)}")
    ray = _import_ray()
    _connect(ray, address)
    try:
        mode = _preflight(ray, tasks, out_dir, outputs)
        if not tasks:
            return
        remote = ray.remote(run_task)
        refs = {
            remote.options(num_cpus=cpus_per_run, max_retries=0, retry_exceptions=False).remote(
                t, mode, worker_cache
            ): t
            for t in tasks
        }
        pending = list(refs)
        try:
            while pending:
                ready, pending = ray.wait(pending, num_returns=1, timeout=0.5)
                for ref in ready:
                    task = refs[ref]
                    try:
                        rec_d, files = ray.get(ref)
                    except ray.exceptions.RayError as e:
                        on_done(_failed(task, e))
                        continue
                    on_done(_materialize(task, rec_d, files))
        except BaseException:
            _cancel(ray, pending)
            raise
    finally:
        ray.shutdown()


def _cancel(ray: Any, pending: list[Any]) -> None:
    """Cancel unfinished tasks: a KeyboardInterrupt in each running one (its run process is
    stopped), then, for those still running after a grace period, the worker is killed."""
    if not pending:
        return
    logger.info(f"eurocslam bench: cancelling {len(pending)} Ray task(s)")
    for ref in pending:
        ray.cancel(ref, force=False)
    _, still = ray.wait(pending, num_returns=len(pending), timeout=CANCEL_GRACE_S)
    for ref in still:
        with contextlib.suppress(Exception):  # already gone
            ray.cancel(ref, force=True)
