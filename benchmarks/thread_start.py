"""What starting and joining a thread costs on this host: the model's `host.thread_start_ns`.

Why: the thesis's renderer starts threads every frame (bp's compositor one `std::async` per
device and per secondary's copy; `parallelCopy` one `std::thread` per part of a copy), so on a
host where a start and join costs tens of microseconds, every device added costs the frame that
many more. The profiles measured by our own runner never needed the figure (its threads are
long-lived), so it is measured here, in C (pthreads, as libstdc++'s std::thread), on the
machine whose renderer a study predicts.

Two figures, each the median over `--trials` trials of the wall time per thread:
- `single_ns`: start one thread that does nothing, join it (a `std::async` per device);
- `batch_ns`: start `--batch` threads, then join them all (a `parallelCopy` of that many parts;
  default: the cores this process may use), per thread.

    PYTHONPATH=. python benchmarks/thread_start.py [--trials 2000] [--batch 16] [--json]

Needs a C compiler (`cc`). Prints one line per figure, or one JSON object with the machine.
"""
from __future__ import annotations

import argparse
import json
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mgpusim.io.workers import usable_cores  # noqa: E402

SOURCE = r"""
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

static void *nothing(void *arg) { return arg; }

static long long now_ns(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (long long)t.tv_sec * 1000000000LL + t.tv_nsec;
}

/* argv: trials, batch. Prints one line per trial: the wall ns to start `batch` threads and
   join them all. */
int main(int argc, char **argv) {
    int trials = atoi(argv[1]), batch = atoi(argv[2]);
    pthread_t *threads = malloc(sizeof(pthread_t) * (size_t)batch);
    for (int i = 0; i < trials; i++) {
        long long start = now_ns();
        for (int k = 0; k < batch; k++)
            if (pthread_create(&threads[k], NULL, nothing, NULL) != 0) return 1;
        for (int k = 0; k < batch; k++) pthread_join(threads[k], NULL);
        printf("%lld\n", now_ns() - start);
    }
    free(threads);
    return 0;
}
"""


def build(folder: Path) -> Path:
    """The probe compiled into `folder` (one error line where there is no compiler)."""
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        raise SystemExit("thread_start: no C compiler (cc); install gcc")
    src, exe = folder / "thread_start.c", folder / "thread_start"
    src.write_text(SOURCE)
    subprocess.run([cc, "-O2", "-pthread", str(src), "-o", str(exe)], check=True)
    return exe


def per_thread_ns(exe: Path, trials: int, batch: int) -> float:
    """Median wall ns per thread over `trials` trials of `batch` starts and joins."""
    out = subprocess.run([str(exe), str(trials), str(batch)], check=True, capture_output=True,
                         text=True).stdout.split()
    return statistics.median(int(v) for v in out) / batch


def measure(trials: int, batch: int) -> dict[str, object]:
    """Both figures, with what they were measured on."""
    with tempfile.TemporaryDirectory() as tmp:
        exe = build(Path(tmp))
        per_thread_ns(exe, max(1, trials // 10), 1)  # warm-up: the loader, the first stacks
        single = per_thread_ns(exe, trials, 1)
        batched = per_thread_ns(exe, trials, batch)
    return {"single_ns": round(single), "batch_ns": round(batched), "batch": batch,
            "trials": trials, "cores": usable_cores(), "machine": platform.node(),
            "processor": platform.processor() or platform.machine()}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=2000)
    ap.add_argument("--batch", type=int, default=None,
                    help="threads started before joining (default: the cores this process may use)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)
    if args.trials < 1 or (args.batch is not None and args.batch < 1):
        ap.error("--trials and --batch must be >= 1")
    batch = args.batch or usable_cores()
    result = measure(args.trials, batch)
    if args.json:
        print(json.dumps(result))
    else:
        print(f"start + join, one thread: {result['single_ns']} ns")
        print(f"start {batch}, then join them: {result['batch_ns']} ns per thread")
    return 0


if __name__ == "__main__":
    sys.exit(main())
