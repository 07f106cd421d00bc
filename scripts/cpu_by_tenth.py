#!/usr/bin/env python3
"""CPU per robot-step in the first and the last tenth of a run's steps.

Starts `swarm run` with the given `--set` overrides, samples every 0.02 s the CPU time (user +
system) of the launcher and every process under it (/proc) and the last step written to the
run's metrics.csv (written as the run goes, a step or two behind it), and once the run has
ended prints the CPU per robot-step and the wall time per step over the first tenth and the
last tenth of its steps, CPU and wall time at a step interpolated between the samples around
it (a run's early steps take ~10 ms each: sampled every 0.1 s without interpolation, a tenth's
ends were off by up to ten steps). Linux only.

    scripts/cpu_by_tenth.py target/release/swarm /tmp/run robots.count=8 world.map=mit_killian_court
"""
import json
import os
import subprocess
import sys
import time


def tree(pid):
    """pid and every process under it."""
    out = [pid]
    try:
        for t in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{t}/children") as f:
                for k in f.read().split():
                    out += tree(int(k))
    except OSError:
        pass
    return out


def cpu_seconds(pids):
    tck = os.sysconf("SC_CLK_TCK")
    total = 0
    for p in pids:
        try:
            with open(f"/proc/{p}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
            total += int(fields[11]) + int(fields[12])
        except (OSError, IndexError, ValueError):
            pass
    return total / tck


def last_step(run):
    """The step of metrics.csv's last row (-1 before there is one)."""
    try:
        with open(os.path.join(run, "metrics.csv"), "rb") as f:
            f.seek(0, 2)
            f.seek(max(0, f.tell() - 4096))
            line = f.read().decode(errors="ignore").strip().split("\n")[-1]
            return int(line.split(",")[0])
    except (OSError, ValueError):
        return -1


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    swarm, run, sets = sys.argv[1], sys.argv[2], sys.argv[3:]
    if os.path.exists(run):
        sys.exit(f"{run} exists: give a new run directory")
    cmd = [swarm, "run", "--quiet", "--out", run]
    for s in sets:
        cmd += ["--set", s]
    child = subprocess.Popen(cmd, stdout=subprocess.DEVNULL)
    samples = []  # (step, cpu seconds, wall seconds)
    pids, seen = [], 0.0
    while child.poll() is None:
        now = time.time()
        if now - seen > 0.5:
            # The processes of a run live as long as it does: look for them twice a second.
            pids, seen = tree(child.pid), now
        # A row caught half written can read as an earlier step: steps only go forward.
        step = max(last_step(run), samples[-1][0] if samples else -1)
        samples.append((step, cpu_seconds(pids), now))
        # Often enough that a step boundary falls between samples a step or so apart.
        time.sleep(0.02)
    with open(os.path.join(run, "summary.json")) as f:
        summary = json.load(f)
    steps, robots = summary["steps"], summary["robots"]
    tenth = steps // 10
    if tenth < 1 or not samples:
        sys.exit(f"the run took {steps} steps: too short to cut in tenths")

    def at(step):
        """CPU and wall time when `step` was reached, interpolated between the samples around it."""
        before = None
        for s, c, t in samples:
            if s >= step:
                if before is None or before[0] == s:
                    return c, t
                s0, c0, t0 = before
                f = (step - s0) / (s - s0)
                return c0 + f * (c - c0), t0 + f * (t - t0)
            before = (s, c, t)
        return samples[-1][1], samples[-1][2]

    def span(first, last):
        (c0, t0), (c1, t1) = at(first), at(last)
        n = last - first
        return 1000 * (c1 - c0) / (robots * n), 1000 * (t1 - t0) / n

    # The last step's rows are written at the run's end: the last tenth stops a step short.
    early = span(0, tenth)
    late = span(steps - 1 - tenth, steps - 2)
    print(f"{steps} steps, {robots} robots, {summary['exit_reason']}")
    print(f"first tenth: {early[0]:.2f} ms of CPU per robot-step, {early[1]:.0f} ms of wall per step")
    print(f"last tenth:  {late[0]:.2f} ms of CPU per robot-step, {late[1]:.0f} ms of wall per step")
    print(f"last ÷ first: {late[0] / early[0]:.2f}×")


if __name__ == "__main__":
    main()
