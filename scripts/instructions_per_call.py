#!/usr/bin/env python3
"""Instructions one function executes per call, in a criterion benchmark, under callgrind.

A benchmark's time on a shared machine swings by several per cent from one run to the next; the
instructions a call executes do not (the same inputs, the same code). This runs the benchmark
binary BENCH with criterion's `--profile-time` (no analysis, a fixed time of iterations) under
valgrind's callgrind, counting only while FUNCTION runs (`--toggle-collect`), and prints the
instructions per call of FUNCTION: the count over the calls, whatever the number of
iterations. Needs valgrind (apt install valgrind). Run it from the benchmark's package directory
when the benchmark reads files relative to it.

    cargo bench -p robot-agent --bench plan --no-run      # prints the binary: target/release/deps/plan-…
    cd robot-agent && ../scripts/instructions_per_call.py ../target/release/deps/plan-… \\
        path_along_16 robot_agent::nav::plan::path_along
"""
import os
import subprocess
import sys
import tempfile


def main():
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    bench, filter_, function = sys.argv[1:]
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "callgrind.out")
        cmd = [
            "valgrind", "--tool=callgrind", "--compress-strings=no", "--compress-pos=no",
            f"--toggle-collect={function}", f"--callgrind-out-file={out}",
            bench, "--bench", filter_, "--profile-time", "1",
        ]
        try:
            run = subprocess.run(cmd, capture_output=True, text=True)
        except FileNotFoundError:
            sys.exit("valgrind not found: apt install valgrind")
        if run.returncode != 0 or not os.path.exists(out):
            sys.exit(f"the benchmark failed:\n{run.stderr[-2000:]}")
        calls, total, callee = 0, 0, None
        with open(out, errors="replace") as f:
            for line in f:
                if line.startswith("cfn="):
                    callee = line[4:].strip()
                elif line.startswith("calls=") and callee == function:
                    calls += int(line[6:].split()[0])
                elif line.startswith("totals:") or line.startswith("summary:"):
                    total = int(line.split()[1])
    if calls == 0:
        sys.exit(f"{function} was not called: give its full path (crate::module::name)")
    print(f"{function}: {calls} calls, {total / calls:,.0f} instructions per call")


if __name__ == "__main__":
    main()
