"""The full fault-injection suite: prints the reliability figures of docs/RELIABILITY.md.

What it does, in this order (about 10-15 minutes on the 2-core development machine):

1. **Training runs killed with SIGKILL.** A tiny Pendulum run (`ilcsan train ... --hidden-width 16`) is
   run once uninterrupted, then again and again killed: at random moments, in the middle of each kind of
   atomic write (a hook, ``ILCSAN_FAULT_DELAY_WRITE``, pauses every write halfway so the kill finds a
   half-written temporary file: config.json, replay segment, metrics.csv, result.json, policy.pt, checkpoint.pt,
   provenance.json),
   several times in a row, and for a two-seed run between the seeds' checkpoints. After each kill every
   checkpoint/policy file on disk must load, none may be older than the last evaluation the process
   reported; then `--resume` runs to the end and each seed's `eval_return_mean` column must equal the
   uninterrupted run's on the same matmul path exactly (as text): a run measures at its start which float32
   path is faster, and two that measured differently round differently.
2. **Grids killed with their workers.** `ilcsan reproduce GRID.toml --workers 2` (two rows, two seeds)
   is killed with its process group at several points, run again to the end and compared with an
   uninterrupted grid (or, for runs that measured another matmul path than it, with their cells trained here on
   the path they recorded).
3. **Bad inputs.** The property tests (tests/test_properties.py) run with ``ILCSAN_PROPERTY_SCALE``
   times their CI example counts, and the hand-written cases of tests/test_reliability.py; the number
   of generated and hand-written inputs is reported (a single failure fails the script).
4. **Servers.** A local Ray is started the way `ilcsan reproduce --backend ray` starts it, and every
   listening socket of its processes is listed: all must be on the loopback interface.

    .venv/bin/python benchmarks/faults.py --json benchmarks/faults.json

Exit code 0 when every figure is as required (0 corrupt, all curves equal, no data lost, loopback only).
"""

from __future__ import annotations

import argparse
import dataclasses
import ipaddress
import json
import os
import platform
import random
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "faults"))

from fault_harness import (  # noqa: E402
    After,
    At,
    During,
    GridSpec,
    References,
    RunSpec,
    grid_curves,
    grid_paths,
    grid_reference_in_process,
    kill_and_resume,
    kill_grid_and_rerun,
    reference_in_process,
    run,
)

WRITES = [".config.json.*.tmp", "replay/.*.tmp", ".metrics.csv.*.tmp", ".policy.pt.*.tmp", ".checkpoint.pt.*.tmp",
          ".result.json.*.tmp", ".provenance.json.*.tmp"]
"""Every file a run writes atomically; config.json and provenance.json are written once per start, the others often."""


def log(message: str) -> None:
    print(message, flush=True)


# ------------------------------------------------------------------------------------------------
# 1. training runs

def training_trials(base: Path, rng: random.Random, scale: float) -> dict:
    single = RunSpec(steps=900, eval_every=150)
    two = RunSpec(steps=600, eval_every=150, seeds="0,1")
    log("reference runs (uninterrupted, separate processes; another on each further matmul path a trial measures) ...")
    references, durations, paths = {}, {}, {}
    for name, spec in (("single", single), ("two seeds", two)):
        references[name] = References(spec, base / f"reference-{name.replace(' ', '-')}", processes=True)
        paths[name], durations[name] = references[name].measured()
        log(f"  {name}: {durations[name]:.1f} s on {paths[name]}, curve {references[name](paths[name])}")
    on_path = dataclasses.replace(single, matmul=paths["single"])
    in_process = reference_in_process(on_path, base / "reference-in-process")
    same_in_process = in_process == references["single"](paths["single"])
    log(f"  in-process run (the CI subset's reference) equals the process run: {same_in_process}")

    def moment(name: str) -> float:
        return rng.uniform(1.0, durations[name] * 0.95)

    plans: list[tuple[str, RunSpec, str, list]] = []
    for index in range(max(1, round(10 * scale))):
        plans.append((f"random moment {index + 1}", single, "single", [At(moment("single"))]))
    for pattern in WRITES:
        occurrence = 1 if pattern.startswith((".config", ".provenance")) else rng.randint(1, 5)
        plans.append((f"mid-write {pattern}", single, "single", [During(pattern, occurrence)]))
    for index in range(max(1, round(3 * scale))):
        # start-up takes ~3 s: early moments leave every resumed process some training to be killed in
        points = [At(rng.uniform(3.5, 6.0)), At(rng.uniform(3.2, 5.0)), During(".checkpoint.pt.*.tmp", 1)]
        plans.append((f"three kills in a row {index + 1}", single, "single", points))
    plans += [
        ("two seeds: between the seeds' checkpoints", two, "two seeds", [During("seed1/.checkpoint*.tmp", 2)]),
        ("two seeds: first seed's checkpoint half-written", two, "two seeds", [During("seed0/.checkpoint*.tmp", 3)]),
        ("two seeds: random moment", two, "two seeds", [At(moment("two seeds"))]),
        ("two seeds: two kills", two, "two seeds", [At(rng.uniform(3.5, 6.0)), During("seed1/.metrics.csv.*.tmp", 2)]),
    ]
    results = []
    for index, (name, spec, reference, points) in enumerate(plans):
        result = kill_and_resume(spec, base / f"trial{index}", points, references[reference], name=name)
        results.append(result)
        status = "ok" if result.survived and not (result.corrupt or result.lost or result.leftovers) else "FAILED"
        log(f"  [{status}] {name}: {result.kills} kill(s) ({'; '.join(result.kill_points)}), checkpoints at "
            f"{result.checkpoint_steps}, resume codes {result.resume_codes}, curve equal {result.curves_equal} "
            f"(on {result.matmul_path}), {result.seconds:.0f} s")
        for problem in result.corrupt + result.lost + result.resume_errors + result.leftovers:
            log(f"      {problem}")
        shutil.rmtree(base / f"trial{index}", ignore_errors=True)
    return {
        "trials": len(results),
        "kills": sum(r.kills for r in results),
        "mid_write_kills": sum(point.startswith("during write") and "finished first" not in point
                               for r in results for point in r.kill_points),
        "kills_survived": sum(r.kills for r in results if r.survived),
        "resumes": sum(len(r.resume_codes) for r in results),
        "resumes_succeeded": sum(code == 0 for r in results for code in r.resume_codes),
        "corrupt": sum(len(r.corrupt) for r in results),
        "curves_equal": sum(r.curves_equal for r in results),
        "data_lost": sum(len(r.lost) for r in results) + sum(not r.curves_equal for r in results),
        "leftovers": sum(len(r.leftovers) for r in results),
        "in_process_equals_process": same_in_process,
        "matmul_paths": sorted({r.matmul_path for r in results if r.matmul_path}),
        "trial_names": [r.name for r in results],
    }


# ------------------------------------------------------------------------------------------------
# 2. grids

def grid_trials(base: Path, rng: random.Random, scale: float) -> dict:
    spec = GridSpec(seeds=2, rows=2, workers=2, steps=1100, eval_every=550)
    log("reference grid (uninterrupted, ilcsan reproduce --workers 2) ...")
    start = time.monotonic()
    straight = base / "grid-reference"
    attempt = run(spec.argv(spec.write(straight), straight / "out"))
    if attempt.returncode != 0:
        raise RuntimeError(f"the reference grid failed: {attempt.stderr[-2000:]}")
    duration = time.monotonic() - start
    reference = grid_curves(straight / "out")
    log(f"  {len(reference)} runs in {duration:.1f} s")
    same_in_process = grid_reference_in_process(straight / "out") == reference
    log(f"  cells trained in-process (the CI subset's reference) equal the grid: {same_in_process}")
    plans = [
        ("between evaluations", [After("**/checkpoint.pt", 0.3)]),
        ("mid-checkpoint of the second seed", [During("**/seed1/.checkpoint*.tmp", 2)]),
        ("mid-replay-segment", [During("**/replay/.*.tmp", 3)]),
    ]
    plans += [(f"random moment {index + 1}", [At(rng.uniform(2.0, duration * 0.9))])
              for index in range(max(1, round(2 * scale)))]
    plans.append(("two kills in a row", [At(rng.uniform(2.0, duration * 0.6)), After("**/checkpoint.pt", 0.5)]))
    trials = []
    for index, (name, points) in enumerate(plans):
        folder = base / f"grid{index}"
        report = kill_grid_and_rerun(spec, folder, points)
        same_paths = report["codes"] == [0] and grid_paths(folder / "out") == grid_paths(straight / "out")
        expected = reference if same_paths or report["codes"] != [0] else grid_reference_in_process(folder / "out")
        report["curves_equal"] = report["curves"] == expected
        report["reference"] = "the uninterrupted grid" if same_paths else "its cells trained here on their paths"
        report["name"] = name
        ok = report["codes"] == [0] and report["curves_equal"] and not (report["corrupt"] or report["leftovers"])
        log(f"  [{'ok' if ok else 'FAILED'}] {name}: {report['kills']} kill(s) ({'; '.join(report['kill_points'])}),"
            f" exit {report['codes']}, curves equal {report['curves_equal']} (to {report['reference']})")
        for problem in report["corrupt"] + report["errors"] + report["leftovers"]:
            log(f"      {problem}")
        trials.append(report)
        shutil.rmtree(folder, ignore_errors=True)
    return {
        "trials": len(trials),
        "kills": sum(t["kills"] for t in trials),
        "kills_survived": sum(t["kills"] for t in trials if t["codes"] == [0] and t["curves_equal"]),
        "corrupt": sum(len(t["corrupt"]) for t in trials),
        "curves_equal": sum(t["curves_equal"] for t in trials),
        "runs_per_grid": len(reference),
        "leftovers": sum(len(t["leftovers"]) for t in trials),
        "in_process_equals_grid": same_in_process,
    }


# ------------------------------------------------------------------------------------------------
# 3. bad inputs

def bad_inputs(base: Path, scale: int) -> dict:
    counts_file = base / "property-counts.json"
    env = dict(os.environ, ILCSAN_PROPERTY_SCALE=str(scale), ILCSAN_PROPERTY_COUNTS=str(counts_file),
               OMP_NUM_THREADS="1", MPLBACKEND="Agg")
    log(f"property tests at {scale}x their CI examples, and the hand-written cases ...")
    start = time.monotonic()
    result = subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider",
                             "tests/test_properties.py", "tests/test_reliability.py"], cwd=ROOT, env=env,
                            capture_output=True, text=True)
    summary = [line.strip("= ") for line in result.stdout.splitlines()
               if re.search(r"\b\d+ (passed|failed)\b.* in [\d.]+s", line)]
    log(f"  pytest: {summary[-1] if summary else result.stdout[-500:]} ({time.monotonic() - start:.0f} s)")
    if result.returncode != 0:
        log(result.stdout[-4000:])
    counts = json.loads(counts_file.read_text()) if counts_file.is_file() else {"examples": {}, "outcomes": {}}
    collected = subprocess.run([sys.executable, "-m", "pytest", "-q", "--collect-only", "-p", "no:cacheprovider",
                                "tests/test_reliability.py"], cwd=ROOT, capture_output=True, text=True)
    handwritten = sum(1 for line in collected.stdout.splitlines() if "::" in line) or sum(
        int(line.rsplit(":", 1)[1]) for line in collected.stdout.splitlines()
        if line.startswith("tests/") and line.rsplit(":", 1)[-1].strip().isdigit())
    generated = sum(counts["examples"].values())
    for name, count in sorted(counts["examples"].items()):
        log(f"  {name}: {count}")
    return {"passed": result.returncode == 0, "generated": generated, "per_property": counts["examples"],
            "outcomes": counts["outcomes"], "handwritten_cases": handwritten,
            "pytest_summary": summary[-1] if summary else ""}


# ------------------------------------------------------------------------------------------------
# 4. servers

RAY_PROBE = r"""
import json, os, socket, struct
from pathlib import Path
from ilcsan.experiments.ray_cluster import ray_node_address, start_local_ray
import ray

def tree(root):
    # this process and all its descendants, from /proc (Linux)
    children = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
            children.setdefault(int(fields[1]), []).append(int(stat.parent.name))
        except (OSError, IndexError, ValueError):
            pass
    found, todo = [], [root]
    while todo:
        pid = todo.pop()
        found.append(pid)
        todo += children.get(pid, [])
    return found

def socket_inodes(pid):
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").glob("*"):
        try:
            target = os.readlink(fd)
        except OSError:
            continue
        if target.startswith("socket:["):
            inodes.add(int(target[8:-1]))
    return inodes

def listening():
    # (address, port, inode) of every listening TCP socket, IPv4 and IPv6
    found = []
    for name, family in (("tcp", socket.AF_INET), ("tcp6", socket.AF_INET6)):
        for line in Path(f"/proc/net/{name}").read_text().splitlines()[1:]:
            fields = line.split()
            if fields[3] != "0A":
                continue
            address, port = fields[1].split(":")
            raw = bytes.fromhex(address)
            raw = b"".join(raw[i:i + 4][::-1] for i in range(0, len(raw), 4))
            found.append((socket.inet_ntop(family, raw), int(port, 16), int(fields[9])))
    return found

def dashboard_url():
    try:
        from ray._private import worker
        return worker.get_dashboard_url() or None
    except Exception:
        return None

start_local_ray(1)
try:
    ours = set()
    for pid in tree(os.getpid()):
        ours |= socket_inodes(pid)
    sockets = [[address, port] for address, port, inode in listening() if inode in ours]
    print(json.dumps({"node": ray_node_address(), "sockets": sockets, "processes": len(tree(os.getpid())),
                      "dashboard": dashboard_url()}))
finally:
    ray.shutdown()
"""


def is_loopback(address: str) -> bool:
    ip = ipaddress.ip_address(address)
    mapped = getattr(ip, "ipv4_mapped", None)
    return (mapped or ip).is_loopback


def ray_servers() -> dict:
    log("starting a local Ray as `reproduce --backend ray` does, listing its listening sockets ...")
    result = subprocess.run([sys.executable, "-c", RAY_PROBE], capture_output=True, text=True, timeout=300,
                            env=dict(os.environ, RAY_ADDRESS="", OMP_NUM_THREADS="1"))
    lines = [line for line in result.stdout.splitlines() if line.startswith("{")]
    if result.returncode != 0 or not lines:
        log(f"  could not start Ray: {result.stderr.strip()[-500:]}")
        return {"checked": False}
    data = json.loads(lines[-1])
    addresses = sorted({ip for ip, _ in data["sockets"]})
    loopback = bool(addresses) and all(is_loopback(ip) for ip in addresses)
    log(f"  node address {data['node']}; {data['processes']} processes, {len(data['sockets'])} listening TCP sockets"
        f" on {addresses}; dashboard {data['dashboard'] or 'off'}")
    return {"checked": True, "node": data["node"], "listening_sockets": len(data["sockets"]),
            "addresses": addresses, "loopback_only": loopback and data["node"] == "127.0.0.1",
            "dashboard": data["dashboard"]}


# ------------------------------------------------------------------------------------------------

def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scale", type=float, default=1.0, help="more (or fewer) kill trials (default 1)")
    parser.add_argument("--property-scale", type=int, default=10, help="property examples x CI's (default 10)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the random kill moments")
    parser.add_argument("--skip", nargs="*", default=[], choices=["training", "grids", "inputs", "ray"])
    parser.add_argument("--json", type=Path, help="also write the figures to this JSON file")
    args = parser.parse_args()
    rng = random.Random(args.seed)
    figures: dict = {"machine": f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}",
                     "date": time.strftime("%Y-%m-%d"), "seed": args.seed}
    start = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="ilcsan-faults-") as folder:
        base = Path(folder)
        if "training" not in args.skip:
            figures["training"] = training_trials(base / "training", rng, args.scale)
        if "grids" not in args.skip:
            figures["grids"] = grid_trials(base / "grids", rng, args.scale)
        if "inputs" not in args.skip:
            figures["inputs"] = bad_inputs(base, args.property_scale)
        if "ray" not in args.skip:
            figures["ray"] = ray_servers()
    figures["minutes"] = round((time.monotonic() - start) / 60, 1)

    ok = True
    log("\n== figures ==")
    if "training" in figures:
        t = figures["training"]
        log(f"training runs: {t['trials']} trials, {t['kills']} kills ({t['mid_write_kills']} in the middle of a "
            f"write), {t['kills_survived']} survived; resumes {t['resumes_succeeded']}/{t['resumes']} succeeded")
        log(f"  checkpoints found corrupt: {t['corrupt']}")
        log(f"  resumed curves equal to the uninterrupted run (exact): {t['curves_equal']}/{t['trials']}")
        log(f"  data lost: {'none' if t['data_lost'] == 0 else t['data_lost']}; temporary files left: "
            f"{t['leftovers']}")
        ok &= t["corrupt"] == 0 and t["curves_equal"] == t["trials"] and t["data_lost"] == 0 and t["leftovers"] == 0
        ok &= t["kills_survived"] == t["kills"] and t["in_process_equals_process"]
    if "grids" in figures:
        g = figures["grids"]
        log(f"grids ({g['runs_per_grid']} runs, 2 workers): {g['trials']} trials, {g['kills']} kills, "
            f"{g['kills_survived']} survived; corrupt {g['corrupt']}; curves equal {g['curves_equal']}/{g['trials']}")
        ok &= g["corrupt"] == 0 and g["curves_equal"] == g["trials"] and g["leftovers"] == 0
    if "inputs" in figures:
        i = figures["inputs"]
        log(f"bad inputs tried: {i['generated']} generated (hypothesis) + {i['handwritten_cases']} hand-written "
            f"cases; all ended in a result or one clear line: {i['passed']}")
        ok &= i["passed"]
    if "ray" in figures and not figures["ray"].get("checked"):
        log("local Ray: not checked (Ray is not installed or did not start)")
    elif "ray" in figures:
        r = figures["ray"]
        log(f"local Ray: {r['listening_sockets']} listening sockets, on {', '.join(r['addresses'])}; loopback only: "
            f"{r['loopback_only']}; dashboard: {r['dashboard'] or 'off'}")
        ok &= r["loopback_only"] and not r["dashboard"]
    log(f"total {figures['minutes']} min; {'ALL FIGURES AS REQUIRED' if ok else 'SOME FIGURES FAILED'}")
    if args.json:
        args.json.write_text(json.dumps(figures, indent=2, sort_keys=True) + "\n")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
