"""Where the evaluator's CPU time goes, down to the compiled kernels: a sampling profile with ``perf``.

    python benchmarks/profile_evaluate.py [--seconds 600] [--runs 40] [--top 25] [--annotate accumulate]

cProfile sees a numba kernel as one opaque call and nothing of what it spends inside; ``perf``
sees the machine code but not its names, because numba registers none. This script compiles the
kernels afresh (a throw-away cache directory, so that their object code is at hand), writes a
``/tmp/perf-<pid>.map`` naming every compiled function's address range (read from the object
code's symbol table), then records ``perf record -e cpu-clock`` of its own process while it
runs both sweeps of a generated drive one after the other in one thread, ``--runs`` times, and
prints ``perf report`` by symbol. ``--annotate NAME`` also prints the function's hottest
instructions (``objdump`` of its object code at the sampled offsets) and its loops by share.

Needs ``perf`` and ``objdump`` (Debian: linux-perf, binutils) and ``kernel.perf_event_paranoid``
≤ 2. The first compile takes about a minute.
"""

from __future__ import annotations

import argparse
import atexit
import collections
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))


def positive(kind):
    def parse(text: str):
        value = kind(text)
        if not value > 0:
            raise argparse.ArgumentTypeError(f"must be positive, got {text}")
        return value
    return parse


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=positive(float), default=600.0, help="length of the generated drive")
    parser.add_argument("--runs", type=positive(int), default=40, help="evaluations (both sweeps) recorded")
    parser.add_argument("--top", type=positive(int), default=25, help="symbols listed")
    parser.add_argument("--annotate", metavar="NAME", help="also list the hottest instructions of this kernel")
    args = parser.parse_args()
    missing = [tool for tool in ("perf", "objdump", "nm") if shutil.which(tool) is None]
    if missing:
        sys.exit(f"profile_evaluate: needs {', '.join(missing)} on PATH (Debian: linux-perf, binutils)")
    work = Path(tempfile.mkdtemp(prefix="excite-profile-"))
    atexit.register(shutil.rmtree, work, ignore_errors=True)
    os.environ["NUMBA_CACHE_DIR"] = str(work / "numba")  # compile afresh: the object code stays at hand

    import numba

    from bench_evaluate import generated
    from excite.core import kernels
    from excite.factors import imu, nonholonomic, odometry, wheel
    from excite.information import elimination, problem
    from excite.information import kernels as information_kernels
    from excite.information.closure import Closure
    from excite.motion import kernels as motion_kernels
    from excite.factors.base import Nominal
    from excite.rig.config import load_rig

    rig = load_rig("robotaxi")
    traj = generated(args.seconds, rig)
    _, nuisance = problem.columns(rig, 1)
    p, closure = nuisance.size, Closure.of(rig)
    K = problem.check_length(Nominal.grid(traj, rig)[1], rig)
    col_map = problem.drive_column_map(rig, 0, 1)
    edges = problem.chunk_edges(K, rig)
    chunks = list(zip(edges[:-1], edges[1:]))
    half = len(chunks) // 2

    def both() -> None:
        elimination.sweep(traj, 0, K - 1, 0, chunks[:half], True, col_map, rig, p, closure)
        elimination.sweep(traj, 0, K - 1, 0, chunks[half:][::-1], False, col_map, rig, p, closure)

    print(f"compiling the kernels in {work} …", file=sys.stderr)
    both()
    entries = []  # (address, size, name, object file, offset in it)
    for module in (kernels, information_kernels, motion_kernels, imu, odometry, wheel, nonholonomic):
        for attr in dir(module):
            dispatcher = getattr(module, attr)
            if not isinstance(dispatcher, numba.core.registry.CPUDispatcher):
                continue
            for i, cres in enumerate(dispatcher.overloads.values()):
                obj = work / f"{module.__name__}.{attr}.{i}.o"
                obj.write_bytes(cres.library._get_compiled_object())
                table = subprocess.run(["nm", "-S", "--defined-only", str(obj)], capture_output=True, text=True).stdout
                for line in table.splitlines():
                    parts = line.split()
                    if len(parts) == 4 and parts[2] in "tT":
                        address = cres.library.get_pointer_to_function(parts[3])
                        if address:
                            entries.append((address, int(parts[1], 16), f"{module.__name__.split('.')[-1]}.{attr}",
                                            obj, int(parts[0], 16)))
    perf_map = Path(f"/tmp/perf-{os.getpid()}.map")
    perf_map.write_text("".join(f"{a:x} {n:x} {name}\n" for a, n, name, _, _ in entries))
    data = work / "perf.data"
    try:
        recorder = subprocess.Popen(["perf", "record", "-q", "-e", "cpu-clock", "-F", "4000", "-o", str(data),
                                     "-p", str(os.getpid())], stderr=subprocess.DEVNULL)
        time.sleep(1.0)
        t0 = time.perf_counter()
        for _ in range(args.runs):
            both()
        elapsed = time.perf_counter() - t0
        recorder.send_signal(signal.SIGINT)
        recorder.wait()
        report = subprocess.run(["perf", "report", "-i", str(data), "--sort", "sym", "--stdio"],
                                capture_output=True, text=True).stdout  # reads the map: before it goes
    finally:
        perf_map.unlink()
    if recorder.returncode not in (0, -signal.SIGINT) or not data.exists():
        sys.exit("profile_evaluate: perf record failed (is kernel.perf_event_paranoid ≤ 2?)")
    print(f"{args.runs} evaluations of a {args.seconds:g} s drive (both sweeps, one thread): "
          f"{elapsed / args.runs * 1e3:.1f} ms each")
    rows = [line for line in report.splitlines() if line.strip() and not line.startswith("#")]
    print("\n".join(line[:110] for line in rows[:args.top]))
    if args.annotate:
        annotate(data, [e for e in entries if e[2].endswith("." + args.annotate)])


def annotate(data: Path, entries: list) -> None:
    """The sampled instructions of one kernel (its first compiled signature), hottest first, and
    the share of its innermost loops (a backward jump's span)."""
    if not entries:
        sys.exit("profile_evaluate: no such kernel")
    address, size, name, obj, offset = entries[0]
    script = subprocess.run(["perf", "script", "-i", str(data), "-F", "ip"], capture_output=True, text=True).stdout
    hits = collections.Counter()
    for line in script.split():
        ip = int(line, 16)
        if address <= ip < address + size:
            hits[ip - address + offset] += 1
    disassembly = subprocess.run(["objdump", "-d", "--no-show-raw-insn", str(obj)], capture_output=True, text=True).stdout
    code = {}
    for line in disassembly.splitlines():
        m = re.match(r"\s*([0-9a-f]+):\s+(.*)", line)
        if m:
            code[int(m.group(1), 16)] = m.group(2)
    total = sum(hits.values()) or 1
    print(f"\n{name}: {total} samples; hottest instructions (object offset)")
    for where, n in hits.most_common(20):
        print(f"{n / total * 100:5.1f} %  {where:6x}  {code.get(where, '?')[:70]}")
    loops = []
    for where, text in code.items():
        m = re.match(r"j\w+\s+([0-9a-f]+)", text)
        if m and int(m.group(1), 16) < where and offset <= where < offset + size:
            loops.append((int(m.group(1), 16), where))
    shares = collections.Counter()
    for where, n in hits.items():
        inner = min((lp for lp in loops if lp[0] <= where <= lp[1]), key=lambda lp: lp[1] - lp[0], default=None)
        shares[inner] += n
    print("innermost loops by share (object offsets)")
    for lp, n in shares.most_common(12):
        span = f"{lp[0]:x}–{lp[1]:x}" if lp else "outside any loop"
        print(f"{n / total * 100:5.1f} %  {span}")


if __name__ == "__main__":
    main()
