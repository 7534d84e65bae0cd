"""Time the reference env's steps (no rendering) with the action formula of `pipeline bench sim`.

usage: bench_reference.py SUITE TASK_ID STEPS   -> prints one JSON line {"steps_per_s": ...}
"""
import json
import math
import sys
import time

import libero_ref as L
from libero_ref import np


def bench_action(t):
    return np.array([0.5 * math.sin(0.1 * t), 0.5 * math.cos(0.13 * t), 0.3 * math.sin(0.07 * t),
                     0.1 * math.sin(0.05 * t), 0.1 * math.cos(0.05 * t), 0.1 * math.sin(0.03 * t),
                     1.0 if math.sin(0.2 * t) >= 0 else -1.0])


def main():
    suite, task_id, steps = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    b, task, bddl = L.task_of(suite, task_id)
    env = L.make_env(bddl)
    env.seed(0)
    env.reset()
    env.set_init_state(b.get_task_init_states(task_id)[0])
    env.step(bench_action(0))  # numba JIT warm-up, not timed
    env.reset()
    env.set_init_state(b.get_task_init_states(task_id)[0])
    t0 = time.perf_counter()
    for t in range(steps):
        env.step(bench_action(t))
    dt = time.perf_counter() - t0
    print(json.dumps(dict(suite=suite, task_id=task_id, steps=steps, steps_per_s=steps / dt)))


if __name__ == "__main__":
    main()
