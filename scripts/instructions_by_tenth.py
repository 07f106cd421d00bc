#!/usr/bin/env python3
"""Instructions per step of one robot in the first and the last tenth of a run's steps.

CPU time on a shared machine swings by a fifth from one run to the next (the same binary, the
same run), which hides changes of a few per cent; the instructions a process executes swing by a
few per cent at most (what its runtime does while it waits depends on timing). This starts
`swarm run` with the given `--set` overrides under valgrind's callgrind, tracing robot 0 alone
(every other process runs natively), asks callgrind to dump robot 0's counts every few steps
while the run goes (`callgrind_control -d`), and once the run has ended prints robot 0's
instructions over the whole run and per step over the first tenth and the last tenth of the
run's steps, the counts at a step interpolated between the dumps around it. The run is a
lockstep run like any other (the world waits for the slow robot), so it is the same run: its
run_digest is printed.
Needs valgrind (apt install valgrind); a complete 8-robot mit_killian_court run takes ~4 min.
The run directory is DIR/run; DIR also keeps the launcher's own callgrind counts.

    scripts/instructions_by_tenth.py target/release/swarm DIR robots.count=8 world.map=mit_killian_court
"""
import glob
import json
import os
import subprocess
import sys
import time

from cpu_by_tenth import last_step  # the step of the run's metrics.csv, read as it goes

EVERY = 10  # steps between dumps


def robot0(run):
    """The pid of robot 0 of the run (None before it started)."""
    out = subprocess.run(
        ["pgrep", "-f", f"robot-agent --id 0 --scenario {run}/"], capture_output=True, text=True
    ).stdout.split()
    return int(out[0]) if out else None


def summary(path):
    with open(path) as f:
        for line in f:
            if line.startswith("summary:"):
                return int(line.split()[1])
    return 0


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    swarm, run, sets = sys.argv[1], os.path.abspath(sys.argv[2]), sys.argv[3:]
    if os.path.exists(run):
        sys.exit(f"{run} exists: give a new run directory")
    os.makedirs(run)
    prefix = os.path.join(run, "callgrind")
    others = ",".join(["world-server", "netem"] + [f"*robot-{i}" for i in range(1, 1000)])
    cmd = [
        "valgrind", "--tool=callgrind", "--trace-children=yes",
        f"--trace-children-skip-by-arg={others}", f"--callgrind-out-file={prefix}.%p",
        swarm, "run", "--quiet", "--out", os.path.join(run, "run"),
    ]
    for s in sets:
        cmd += ["--set", s]
    rundir = os.path.join(run, "run")
    try:
        child = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    except FileNotFoundError:
        sys.exit("valgrind not found: apt install valgrind")
    pid = None
    while pid is None and child.poll() is None:
        pid = robot0(rundir)
        time.sleep(0.2)
    if pid is None:
        sys.exit(f"the run ended before robot 0 started: see {rundir}")
    dumps = []  # the step (midpoint of before and after the dump), in order
    next_at = EVERY
    while child.poll() is None:
        step = last_step(rundir)
        if step >= next_at:
            subprocess.run(["callgrind_control", "-d", str(pid)], capture_output=True)
            after = last_step(rundir)
            dumps.append((step + after) / 2)
            next_at = max(after, step) + EVERY
            print(f"\rstep {after}", end="", file=sys.stderr, flush=True)
        time.sleep(0.05)
    print(file=sys.stderr)
    with open(os.path.join(rundir, "summary.json")) as f:
        s = json.load(f)
    steps = s["steps"]
    # Cumulative counts at each dump; the final file (no suffix) holds the rest to the end.
    parts = sorted(glob.glob(f"{prefix}.{pid}.*"), key=lambda p: int(p.rsplit(".", 1)[1]))
    counts = [summary(p) for p in parts]
    final = summary(f"{prefix}.{pid}")
    for p in parts + [f"{prefix}.{pid}"]:
        os.remove(p)
    print(f"{steps} steps, {s['robots']} robots, {s['exit_reason']}, run_digest {s['run_digest'][:8]}")
    print(f"robot 0, whole run: {(sum(counts) + final) / 1e6:.0f} M instructions")
    if len(counts) != len(dumps):
        sys.exit(f"{len(dumps)} dumps asked, {len(counts)} written: the tenths need a quieter machine")
    points, total = [(0.0, 0)], 0
    for at, c in zip(dumps, counts):
        total += c
        points.append((at, total))
    points.append((float(steps - 1), total + final))

    def at(step):
        for (s0, c0), (s1, c1) in zip(points, points[1:]):
            if s0 <= step <= s1:
                return c0 + (c1 - c0) * (step - s0) / max(s1 - s0, 1e-9)
        return points[-1][1]

    tenth = steps // 10
    early = (at(tenth) - at(0)) / tenth
    # As cpu_by_tenth.py: the last tenth stops a step short of the end.
    late = (at(steps - 2) - at(steps - 1 - tenth)) / (tenth - 1)
    print(f"robot 0, first tenth: {early / 1e6:.2f} M instructions per step")
    print(f"robot 0, last tenth:  {late / 1e6:.2f} M instructions per step")
    print(f"last ÷ first: {late / early:.2f}×")


if __name__ == "__main__":
    main()
