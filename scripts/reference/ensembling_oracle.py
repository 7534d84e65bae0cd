"""What the reference ensembling rules execute of the action chunks a Python policy host recorded
(LIBERO_EVAL_HOST_RECORD: one episode, one call per query, in order), for tests/ensembling.rs.

    ensembling_oracle.py RULE RECORD_DIR STEPS   ->  one JSON line: {"query_steps", "actions"}

RULE is the pipeline's ensemble= text. The rules run from their packages, in the venv that has
them (the test picks it):
- newest:N, average:N, ema:ALPHA:N: vla-eval's ActionChunkBuffer and get_ensemble_fn
  (vla_eval.model_servers.chunking, the vla-eval venv), pushed a chunk whenever the buffer is empty
  or N actions ran since the last push;
- temporal:K: lerobot's ACTTemporalEnsembler (the lerobot venv), a chunk every step;
- adaptive:H:ALPHA: vla-eval's packaging of starVLA's AdaptiveEnsembler
  (vla_eval.model_servers.starvla._AdaptiveEnsembler), a chunk every step, in float64.
"""

import glob
import json
import os
import sys

import numpy as np


def recorded_chunks(record):
    calls = sorted(glob.glob(os.path.join(record, "call-*.npz")))
    out = []
    for path in calls:
        with np.load(path) as z:
            assert z["actions"].shape[0] == 1, f"{path}: one episode per call expected"
            out.append((int(z["policy_step"][0]), z["actions"][0]))
    return out


def blend(rule, chunks, steps):
    from vla_eval.model_servers.chunking import ActionChunkBuffer, get_ensemble_fn

    if rule[0] == "ema":
        fn, every = get_ensemble_fn("ema", ema_alpha=float(rule[1])), int(rule[2])
    else:
        fn, every = get_ensemble_fn(rule[0]), int(rule[1])
    buffer = ActionChunkBuffer(len(chunks[0][1]), fn)
    queries, actions, executed, next_chunk = [], [], 0, iter(chunks)
    for step in range(steps):
        if buffer.empty or executed >= every:
            _, chunk = next(next_chunk)
            buffer.push_chunk(chunk)
            queries.append(step)
            executed = 0
        actions.append(buffer.pop())
        executed += 1
    return queries, actions


def temporal(coeff, chunks, steps):
    import torch
    from lerobot.policies.act.modeling_act import ACTTemporalEnsembler

    ensembler = ACTTemporalEnsembler(coeff, len(chunks[0][1]))
    actions = []
    for _, chunk in chunks[:steps]:
        actions.append(ensembler.update(torch.from_numpy(chunk)[None])[0].numpy())
    return list(range(steps)), actions


def adaptive(horizon, alpha, chunks, steps):
    # The module imports OpenCV and transforms3d for its server's image and rotation handling,
    # which the ensembler (NumPy only) does not use and the vla-eval venv does not install: empty
    # stand-ins let the module load where they are missing.
    import importlib.util
    import types

    for name in ("cv2", "transforms3d"):
        if importlib.util.find_spec(name) is None:
            sys.modules[name] = types.ModuleType(name)
            if name == "transforms3d":
                sys.modules["transforms3d.euler"] = types.SimpleNamespace(euler2axangle=None)
    from vla_eval.model_servers.starvla import _AdaptiveEnsembler

    ensembler = _AdaptiveEnsembler(horizon, alpha)
    actions = [ensembler(chunk.astype(np.float64)).astype(np.float32) for _, chunk in chunks[:steps]]
    return list(range(steps)), actions


def main(rule_text, record, steps):
    rule, steps = rule_text.split(":"), int(steps)
    chunks = recorded_chunks(record)
    if rule[0] in ("newest", "average", "ema"):
        queries, actions = blend(rule, chunks, steps)
    elif rule[0] == "temporal":
        queries, actions = temporal(float(rule[1]), chunks, steps)
    elif rule[0] == "adaptive":
        queries, actions = adaptive(int(rule[1]), float(rule[2]), chunks, steps)
    else:
        raise SystemExit(f"unknown rule {rule_text}")
    recorded_steps = [s for s, _ in chunks]
    print(json.dumps({
        "query_steps": queries,
        "recorded_query_steps": recorded_steps,
        "actions": [[float(x) for x in np.asarray(a, dtype=np.float32)] for a in actions],
    }))


if __name__ == "__main__":
    main(*sys.argv[1:])
