"""The benchmarks' one timer: the best of a few runs, so a busy shared machine distorts it least."""

import time


def best_of(fn, repeats=5, clock=time.perf_counter):
    """Smallest elapsed ``clock()`` time (s) of ``repeats`` calls of ``fn()``.

    ``clock=time.process_time`` counts this process's CPU time only (other processes cannot inflate it).
    """
    times = []
    for _ in range(repeats):
        t0 = clock()
        fn()
        times.append(clock() - t0)
    return min(times)
