"""Run every ``benchmarks/bench_*.py`` script (``make bench``), one after another.

Each script writes its own numbers to ``benchmarks/results/``. This driver runs them in
separate processes with the current interpreter, prints a one-line status per script and
exits non-zero if any failed. ``python benchmarks/run.py sh resample`` runs only the scripts
whose names contain one of the given words.
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main(argv: list[str]) -> int:
    scripts = sorted(HERE.glob("bench_*.py"))
    if argv:
        scripts = [s for s in scripts if any(word in s.stem for word in argv)]
    if not scripts:
        print(f"no benchmark matches {argv}", file=sys.stderr)
        return 2
    failed = []
    for script in scripts:
        t0 = time.perf_counter()
        print(f"[bench] {script.name} ...", flush=True)
        proc = subprocess.run([sys.executable, str(script)], cwd=HERE.parent, capture_output=True, text=True)
        status = "ok" if proc.returncode == 0 else f"FAILED (exit {proc.returncode})"
        print(f"[bench] {script.name}: {status} in {time.perf_counter() - t0:.1f} s", flush=True)
        if proc.returncode:
            failed.append(script.name)
            sys.stderr.write(proc.stderr[-4000:])
    written = sorted(p.name for p in (HERE / "results").glob("*") if p.is_file())
    print(f"[bench] results in benchmarks/results/: {', '.join(written)}")
    if failed:
        print(f"[bench] failed: {', '.join(failed)}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
