#!/usr/bin/env python3
"""The information floor of a run's radio traffic, and how far above it the run's bytes are.

The floor: the map the team has to learn -- the truth's reachable free cells and the walls that
bound them, everything else unknown (`grids/truth_reachable.pgm`, which `swarm run` writes) --
compressed with lzma (xz, preset 9 extreme), once for every robot but one: each robot must come
to know the whole map, and at least one robot sees each part itself. No exchange that delivers
the complete map to every robot can send less on average than this (a generic compressor's
estimate of the map's information, not a proven lower bound).

    scripts/information_floor.py RUN_DIR [RUN_DIR ...]

Prints per run: the map's cells, its lzma bytes, the floor, the run's wire and payload bytes
(summary.json) and their ratios to the floor. Standard library only.
"""

import json
import lzma
import sys
from pathlib import Path


def read_pgm(path):
    """The cells of a binary PGM (P5, maxval 255) as bytes, row by row."""
    data = path.read_bytes()
    fields, pos = [], 0
    while len(fields) < 4:
        while data[pos:pos + 1].isspace():
            pos += 1
        if data[pos:pos + 1] == b"#":
            pos = data.index(b"\n", pos) + 1
            continue
        end = pos
        while not data[end:end + 1].isspace():
            end += 1
        fields.append(data[pos:end])
        pos = end
    magic, width, height, maxval = fields[0], int(fields[1]), int(fields[2]), int(fields[3])
    if magic != b"P5" or maxval != 255:
        raise ValueError(f"{path}: not an 8-bit binary PGM")
    cells = data[pos + 1:pos + 1 + width * height]
    if len(cells) != width * height:
        raise ValueError(f"{path}: {len(cells)} cells for {width}x{height}")
    return width, height, cells


def floor(run):
    run = Path(run)
    width, height, cells = read_pgm(run / "grids" / "truth_reachable.pgm")
    summary = json.loads((run / "summary.json").read_text())
    robots = summary["robots"]
    packed = lzma.compress(cells, preset=9 | lzma.PRESET_EXTREME)
    floor_bytes = len(packed) * max(robots - 1, 1)
    wire, payload = summary["bytes_wire_total"], summary["bytes_payload_total"]
    return {
        "run": str(run),
        "robots": robots,
        "cells": width * height,
        "map_lzma_bytes": len(packed),
        "floor_bytes": floor_bytes,
        "wire_bytes": wire,
        "payload_bytes": payload,
        "wire_over_floor": round(wire / floor_bytes, 1),
        "payload_over_floor": round(payload / floor_bytes, 1),
    }


def main(argv):
    if len(argv) < 2 or argv[1] in ("-h", "--help"):
        print(__doc__.strip())
        return 0 if len(argv) >= 2 else 2
    status = 0
    for run in argv[1:]:
        try:
            print(json.dumps(floor(run)))
        except (OSError, ValueError, KeyError) as e:
            print(f"information_floor: {run}: {e}", file=sys.stderr)
            status = 1
    return status


if __name__ == "__main__":
    sys.exit(main(sys.argv))
