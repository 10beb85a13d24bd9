"""Fixed costs of the command line: ``solidkit --help`` and ``solidkit <group> --help`` against ``python -c pass``.

Peer: the bare interpreter (``python -c pass``), run in turn with each command (A B A B ..., after one warm-up
of each) so that the ratio holds when the machine's speed drifts. Reported: the median wall time of each and
the median of the per-pair ratios. Writes ``benchmarks/results/cli_startup.{json,md}``.
"""

from __future__ import annotations

import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
RUNS = 9
SOLIDKIT = [sys.executable, "-m", "solidkit.cli"]
PEER = [sys.executable, "-c", "pass"]
COMMANDS = {
    "solidkit --help": ["--help"],
    "solidkit capture --help": ["capture", "--help"],
    "solidkit testset --help": ["testset", "--help"],
}


def wall(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=False)
    return time.perf_counter() - t0


def main() -> None:
    results = {}
    for name, args in COMMANDS.items():
        cmd = SOLIDKIT + args
        wall(cmd), wall(PEER)  # warm-up
        pairs = [(wall(cmd), wall(PEER)) for _ in range(RUNS)]
        a, b = [p[0] for p in pairs], [p[1] for p in pairs]
        results[name] = {
            "median_s": statistics.median(a),
            "peer_median_s": statistics.median(b),
            "ratio_median": statistics.median(x / y for x, y in pairs),
            "runs": RUNS,
        }
    out = HERE / "results"
    (out / "cli_startup.json").write_text(json.dumps({"peer": "python -c pass", "results": results}, indent=2) + "\n")
    rows = [
        f"| `{n}` | {r['median_s']:.3f} | {r['peer_median_s']:.3f} | {r['ratio_median']:.1f} |"
        for n, r in results.items()
    ]
    (out / "cli_startup.md").write_text(
        "# Command-line start-up\n\nMedian wall time of each command and of `python -c pass` run in turn with it "
        f"({RUNS} pairs after a warm-up), and the median per-pair ratio.\n\n"
        "| command | median (s) | `python -c pass` (s) | ratio |\n|---|---|---|---|\n" + "\n".join(rows) + "\n"
    )
    print("\n".join(rows))


if __name__ == "__main__":
    main()
