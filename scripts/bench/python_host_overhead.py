"""The Python host's cost per call against calling the same lerobot policy directly in Python, on a
full-size π0.5 (4.1 B parameters, lerobot 0.6.1's own PI05Policy, random bf16 weights) or any
lerobot checkpoint (issue 45; figures in data/benchmarks/python-host-*/).

    python python_host_overhead.py build DIR            # π0.5 4.1 B random bf16 + processors, a local tokenizer
    python python_host_overhead.py time DIR OUT.json [--device cuda:0] [--batches 1,8,32] [--reps 5]

`time` feeds both paths the same batch (random 360 x 360 cameras, a LIBERO-like state): directly,
the adapter the host runs (policies/python/lerobot_policy.py: LerobotPolicy.act); through the
host, libero_eval_host.py started as the pipeline starts it, the frames over its pipes. The
difference is what the process boundary costs a call (encode, copy through the pipe, decode).
"""

import json
import os
import statistics
import struct
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
HOST_DIR = os.path.join(HERE, "..", "..", "policies", "python")


def build(out):
    import torch
    from tokenizers import Tokenizer, models, pre_tokenizers, processors
    from transformers import PreTrainedTokenizerFast
    from lerobot.configs import FeatureType, PolicyFeature
    from lerobot.policies.pi05.configuration_pi05 import PI05Config
    from lerobot.policies.pi05.modeling_pi05 import PI05Policy
    import lerobot.policies.pi05.processor_pi05 as P

    t0 = time.time()
    tok_dir = os.path.join(out, "tokenizer")
    # A character-level stand-in for PaliGemma's gated tokenizer (ids < 257152, a pad token).
    chars = list(" abcdefghijklmnopqrstuvwxyz0123456789.,;:!?-_'\"()\n")
    vocab = {"<pad>": 0, "<eos>": 1, "<bos>": 2, "<unk>": 3, **{c: i + 4 for i, c in enumerate(chars)}}
    tk = Tokenizer(models.WordLevel(vocab=vocab, unk_token="<unk>"))
    tk.pre_tokenizer = pre_tokenizers.Split("", "isolated")
    tk.post_processor = processors.TemplateProcessing(single="<bos> $A", special_tokens=[("<bos>", 2)])
    PreTrainedTokenizerFast(tokenizer_object=tk, pad_token="<pad>", bos_token="<bos>", eos_token="<eos>",
                            unk_token="<unk>").save_pretrained(tok_dir)
    device = "cuda" if torch.cuda.is_available() else "cpu"
    cfg = PI05Config(dtype="bfloat16", device=device, push_to_hub=False, n_action_steps=10,
                     input_features={"observation.images.image": PolicyFeature(FeatureType.VISUAL, (3, 256, 256)),
                                     "observation.images.image2": PolicyFeature(FeatureType.VISUAL, (3, 256, 256)),
                                     "observation.state": PolicyFeature(FeatureType.STATE, (8,))},
                     output_features={"action": PolicyFeature(FeatureType.ACTION, (7,))})
    torch.manual_seed(0)
    policy = PI05Policy(cfg)
    stats = {"observation.state": {"q01": -torch.ones(8), "q99": torch.ones(8)},
             "action": {"q01": -torch.ones(7), "q99": torch.ones(7)}}
    orig = P.TokenizerProcessorStep
    P.TokenizerProcessorStep = lambda **kw: orig(**{**kw, "tokenizer_name": os.path.abspath(tok_dir)})
    pre, post = P.make_pi05_pre_post_processors(cfg, dataset_stats=stats)
    P.TokenizerProcessorStep = orig
    policy.save_pretrained(out)
    pre.save_pretrained(out)
    post.save_pretrained(out)
    n = sum(p.numel() for p in policy.parameters())
    print(json.dumps({"built": out, "parameters": n, "seconds": round(time.time() - t0, 1)}))


def batch_of(b, size=360, seed=0):
    rng = np.random.default_rng(seed)
    quat = np.tile([0.9998, 0.0, 0.0, 0.02], (b, 1))
    return {
        "agentview": rng.integers(0, 256, (b, size, size, 3), dtype=np.uint8),
        "wrist": rng.integers(0, 256, (b, size, size, 3), dtype=np.uint8),
        "eef_pos": rng.normal(0, 0.1, (b, 3)), "eef_quat": quat, "eef_mat": np.tile(np.eye(3), (b, 1, 1)),
        "gripper_qpos": np.full((b, 2), 0.02), "gripper_qvel": np.zeros((b, 2)),
        "joint_pos": np.zeros((b, 7)), "joint_vel": np.zeros((b, 7)),
    }


def frame(header, arrays):
    meta, parts, off = {}, [], 0
    for k, a in arrays.items():
        a = np.ascontiguousarray(a)
        meta[k] = {"dtype": a.dtype.str.lstrip("<|="), "shape": list(a.shape), "offset": off}
        parts.append(a.tobytes())
        off += a.nbytes
    h = json.dumps(dict(header, arrays=meta)).encode()
    return struct.pack("<IQ", len(h), off) + h + b"".join(parts)


def read_frame(f):
    hl, bl = struct.unpack("<IQ", f.read(12))
    h = json.loads(f.read(hl))
    f.read(bl)
    return h


def time_both(ckpt, out_json, device, batches, reps):
    import torch

    sys.path.insert(0, HOST_DIR)
    import lerobot_policy

    tok = os.path.join(ckpt, "tokenizer")
    options = {"tokenizer": tok} if os.path.isdir(tok) else {}
    sync = torch.cuda.synchronize if torch.cuda.is_available() else (lambda: None)
    results = {"checkpoint": ckpt, "device": device, "reps": reps, "torch": torch.__version__, "rows": []}
    t0 = time.time()
    direct = lerobot_policy.LerobotPolicy(ckpt, device, dict(options))
    results["direct_load_s"] = round(time.time() - t0, 1)
    results["describe"] = {k: v for k, v in direct.describe().items() if k != "checkpoint_sha256"}
    host = subprocess.Popen(
        [sys.executable, "-u", os.path.join(HOST_DIR, "libero_eval_host.py"), "--target", f"lerobot:{ckpt}",
         "--device", device, "--option", "benchmark=libero"] + [f"--option={k}={v}" for k, v in options.items()],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    t0 = time.time()
    ready = read_frame(host.stdout)
    assert ready["op"] == "ready", ready
    results["host_load_s"] = round(time.time() - t0, 1)
    for b in batches:
        arrays = batch_of(b)
        eps = [{"task": "put the black bowl on the plate", "seed": 1000 + i, "policy_step": 0} for i in range(b)]
        batch = dict(arrays, task=[e["task"] for e in eps], seed=np.array([e["seed"] for e in eps], dtype=np.uint64),
                     policy_step=np.zeros(b, dtype=np.int64))
        d_ms, h_ms = [], []
        for rep in range(reps + 2):  # two warm-up calls each
            sync(); t = time.perf_counter(); direct.act(batch); sync()
            d = (time.perf_counter() - t) * 1e3
            payload = frame({"op": "act", "episodes": eps}, arrays)
            t = time.perf_counter()
            host.stdin.write(payload); host.stdin.flush()
            reply = read_frame(host.stdout)
            h = (time.perf_counter() - t) * 1e3
            assert reply["op"] == "actions", reply
            if rep >= 2:
                d_ms.append(d); h_ms.append(h)
        row = {"batch": b, "frame_mb": round(len(payload) / 1e6, 2),
               "direct_ms_median": round(statistics.median(d_ms), 2),
               "host_ms_median": round(statistics.median(h_ms), 2)}
        row["overhead_ms"] = round(row["host_ms_median"] - row["direct_ms_median"], 2)
        row["overhead_pct"] = round(100 * row["overhead_ms"] / row["direct_ms_median"], 2)
        results["rows"].append(row)
        print(json.dumps(row), flush=True)
    host.stdin.close()
    host.wait()
    json.dump(results, open(out_json, "w"), indent=1)


if __name__ == "__main__":
    if sys.argv[1] == "build":
        build(sys.argv[2])
    elif sys.argv[1] == "time":
        import argparse

        p = argparse.ArgumentParser()
        p.add_argument("cmd")
        p.add_argument("ckpt")
        p.add_argument("out")
        p.add_argument("--device", default="cuda:0")
        p.add_argument("--batches", default="1,8,32")
        p.add_argument("--reps", type=int, default=5)
        a = p.parse_args()
        time_both(a.ckpt, a.out, a.device, [int(x) for x in a.batches.split(",")], a.reps)
    else:
        sys.exit(f"unknown command {sys.argv[1]!r}")
