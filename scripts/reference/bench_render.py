"""Time the reference env's camera rendering (robosuite's offscreen EGL renderer), for `pipeline bench render`.

usage: bench_render.py SUITE TASK_ID FRAMES SIZE   -> prints one JSON line {"pairs_per_s": ...}
A "pair" is agentview + robot0_eye_in_hand at SIZE x SIZE, rendered with `sim.render` as the
camera observables do, on the init state of episode 0 (no physics in the timed loop).
"""
import json
import sys
import time

import libero_ref as L

CAMERAS = ("agentview", "robot0_eye_in_hand")


def main():
    suite, task_id, frames, size = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
    b, task, bddl = L.task_of(suite, task_id)
    env = L.make_env(bddl, has_offscreen_renderer=True, use_camera_obs=True, camera_names=list(CAMERAS),
                     camera_heights=size, camera_widths=size)
    env.seed(0)
    env.reset()
    env.set_init_state(b.get_task_init_states(task_id)[0])
    for cam in CAMERAS:  # warm-up (context and uploads), not timed
        env.sim.render(camera_name=cam, width=size, height=size)
    t0 = time.perf_counter()
    for _ in range(frames):
        for cam in CAMERAS:
            env.sim.render(camera_name=cam, width=size, height=size)
    dt = time.perf_counter() - t0
    print(json.dumps(dict(suite=suite, task_id=task_id, frames=frames, size=size, pairs_per_s=frames / dt)))


if __name__ == "__main__":
    main()
