"""Read a dataset `pipeline export --format lerobot` wrote with lerobot 0.6.1's own LeRobotDataset
(offline) and compare every frame with what the run stored and, for LIBERO, with what the policy
saw (the observations its Python host recorded, LIBERO_EVAL_HOST_RECORD). For tests/export.rs.

    python lerobot_dataset_check.py DATASET RUN [RECORD_DIR]

Prints one JSON object: the dataset's length, fps, episodes and tasks, and the largest differences
found (images in 0..255 levels, states and actions in their units).
"""

import glob
import json
import os
import sys

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import numpy as np
import pyarrow.parquet as pq
import torch
from lerobot.datasets.lerobot_dataset import LeRobotDataset
from lerobot.processor.env_processor import LiberoProcessorStep


def stored_steps(run):
    rows = {}
    for part in glob.glob(os.path.join(run, "steps", "*.parquet")):
        t = pq.read_table(part).to_pydict()
        for i in range(len(t["step"])):
            rows.setdefault(t["episode_key"][i], []).append({k: t[k][i] for k in t})
    return {k: sorted(v, key=lambda r: r["step"]) for k, v in rows.items()}


def recorded_calls(record):
    """Per task text: the host's calls in policy-step order (one episode per task in the tests)."""
    calls = {}
    for f in sorted(glob.glob(os.path.join(record, "*.npz"))):
        z = np.load(f)
        tasks = json.loads(str(z["task_json"]))
        for b, task in enumerate(tasks):
            calls.setdefault(task, []).append({k: z[k][b] for k in z.files if k != "task_json"})
    return {t: sorted(c, key=lambda c: int(c["policy_step"])) for t, c in calls.items()}


def main(dataset, run, record=None):
    meta = json.load(open(os.path.join(dataset, "meta", "libero_eval.json")))
    keys = [e["episode_key"] for e in meta["episodes"]]
    backend = os.environ.get("VIDEO_BACKEND", "pyav")
    ds = LeRobotDataset(repo_id="local/export", root=dataset, video_backend=backend, return_uint8=True)
    steps = stored_steps(run)
    calls = recorded_calls(record) if record else None
    quat2aa = LiberoProcessorStep()._quat2axisangle
    out = {"len": len(ds), "fps": ds.fps, "episodes": ds.num_episodes, "tasks": [], "frames": [],
           "max_image_diff": 0, "max_state_diff": 0.0, "max_action_diff": 0.0, "max_policy_action_diff": 0.0,
           "max_reward_diff": 0.0, "success_mismatches": 0, "done": 0, "held_frames": 0, "held_mismatches": 0}
    cameras = [k for k in ds.meta.features if k.startswith("observation.images.")]
    for i in range(len(ds)):
        item = ds[i]
        e, f = int(item["episode_index"]), int(item["frame_index"])
        key = keys[e]
        rows = [r for r in steps[key] if r["policy_step"] is not None]
        step = rows[f]
        action = item["action"].numpy()
        out["max_action_diff"] = max(out["max_action_diff"], float(np.abs(action - np.array(step["action"], dtype=np.float32)).max()))
        out["success_mismatches"] += int(bool(item["next.success"]) != bool(step["goal"]))
        out["done"] += int(bool(item["next.done"]))
        if "held" in item:
            out["held_frames"] += int(bool(item["held"]))
            out["held_mismatches"] += int(bool(item["held"]) != bool(step["held"]))
        if f == 0:
            out["tasks"].append(item["task"])
            out["frames"].append(0)
        out["frames"][-1] += 1
        state = item["observation.state"].numpy()
        if "reward" in step:
            # ALOHA-sim: agent_pos before the step (the previous step's stored one; the reset's at 0)
            out["max_reward_diff"] = max(out["max_reward_diff"], abs(float(item["next.reward"]) - step["reward"]))
            if f > 0:
                before = np.array(rows[f - 1]["agent_pos"], dtype=np.float32)
                out["max_state_diff"] = max(out["max_state_diff"], float(np.abs(state - before).max()))
        if calls is not None:
            call = calls[item["task"]][f]
            assert int(call["policy_step"]) == f, (key, f, int(call["policy_step"]))
            # what the policy saw, rotated 180° as lerobot's LIBERO processor does
            for cam, raw in [("observation.images.image", call["agentview"]), ("observation.images.image2", call["wrist"])]:
                exported = item[cam].numpy().transpose(1, 2, 0)
                seen = raw[::-1, ::-1]
                out["max_image_diff"] = max(out["max_image_diff"], int(np.abs(exported.astype(int) - seen.astype(int)).max()))
            aa = quat2aa(torch.tensor(call["eef_quat"][None], dtype=torch.float64))[0].numpy()
            expected = np.concatenate([call["eef_pos"].astype(np.float32), aa, call["gripper_qpos"].astype(np.float32)])
            out["max_state_diff"] = max(out["max_state_diff"], float(np.abs(state - expected).max()))
            out["max_policy_action_diff"] = max(out["max_policy_action_diff"], float(np.abs(action - call["actions"][0]).max()))
        assert all(item[c].shape[0] == 3 for c in cameras)
    out["image_shapes"] = {c: list(ds[0][c].shape) for c in cameras}
    out["stats_keys"] = sorted(ds.meta.stats.keys()) if ds.meta.stats else []
    print(json.dumps(out))


if __name__ == "__main__":
    main(*sys.argv[1:])
