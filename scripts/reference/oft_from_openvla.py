"""An OpenVLA-OFT 7B checkpoint with random weights, made from an OpenVLA-7B one on the GPU machine
(torch only: no transformers, timm or openvla-oft there, and no room to carry 15 GB).

usage: oft_from_openvla.py OPENVLA_DIR OUT_DIR [--seed 1]

OFT's LIBERO checkpoints (`moojink/openvla-7b-oft-finetuned-libero-*`) are OpenVLA-7B's backbone with
SDPA attention plus two heads, so OUT_DIR gets OPENVLA_DIR's files as links (the shards, their index,
config.json, the preprocessor and tokenizer files) and what OFT adds, as oft_bench.py writes them:

- dataset_statistics.json: OPENVLA_DIR's, each key's `proprio` replaced by oft_tiny.stats_with_proprio's
  (LIBERO-like q01/q99 of the 8-dim state; OpenVLA's file has zeros there);
- `action_head--150000_checkpoint.pt`: L1RegressionActionHead (MLPResNet with 2 blocks at the LLM's
  width 4096, input 7 x 4096) and `proprio_projector--150000_checkpoint.pt` (fc1 8 -> 4096, fc2 4096
  -> 4096), torch.save of bf16 state dicts with DDP's `module.` prefix, drawn as
  oft_tiny.randomize_head draws them (LayerNorm weights 1 + 0.2 N, biases 0.1 N, matrices N / sqrt(fan_in)).

The weights are random: for speed and memory figures, not success rates.
"""

import argparse
import collections
import json
import os

import numpy as np
import torch

LLM_DIM, ACTION_DIM, CHUNK, PROPRIO_DIM, STEP = 4096, 7, 8, 8, 150000


def head_shapes():
    """(name, shape) of the two heads' state dicts, as oft_tiny.py's modules name them."""
    action_head = [("model.layer_norm1.weight", [LLM_DIM * ACTION_DIM]), ("model.layer_norm1.bias", [LLM_DIM * ACTION_DIM]),
                   ("model.fc1.weight", [LLM_DIM, LLM_DIM * ACTION_DIM]), ("model.fc1.bias", [LLM_DIM])]
    for b in range(2):
        action_head += [(f"model.mlp_resnet_blocks.{b}.ffn.0.weight", [LLM_DIM]),
                        (f"model.mlp_resnet_blocks.{b}.ffn.0.bias", [LLM_DIM]),
                        (f"model.mlp_resnet_blocks.{b}.ffn.1.weight", [LLM_DIM, LLM_DIM]),
                        (f"model.mlp_resnet_blocks.{b}.ffn.1.bias", [LLM_DIM])]
    action_head += [("model.layer_norm2.weight", [LLM_DIM]), ("model.layer_norm2.bias", [LLM_DIM]),
                    ("model.fc2.weight", [ACTION_DIM, LLM_DIM]), ("model.fc2.bias", [ACTION_DIM])]
    projector = [("fc1.weight", [LLM_DIM, PROPRIO_DIM]), ("fc1.bias", [LLM_DIM]),
                 ("fc2.weight", [LLM_DIM, LLM_DIM]), ("fc2.bias", [LLM_DIM])]
    return {"action_head": action_head, "proprio_projector": projector}


def draw(name, shape, gen):
    if len(shape) == 1 and "norm" in name and name.endswith("weight"):
        x = 1.0 + 0.2 * torch.randn(shape, generator=gen)
    elif len(shape) == 1:
        x = 0.1 * torch.randn(shape, generator=gen)
    else:
        x = torch.randn(shape, generator=gen) / np.sqrt(shape[1])
    return x.to(torch.bfloat16)


def proprio_stats():
    """oft_tiny.stats_with_proprio's proprio entry (the same seed and ranges)."""
    rng = np.random.RandomState(11)
    center = np.array([0.0, 0.0, 1.0, 3.0, 0.0, 0.0, 0.02, -0.02])
    half = np.array([0.3, 0.3, 0.3, 0.5, 0.5, 0.5, 0.02, 0.02]) * rng.uniform(0.8, 1.2, 8)
    q01, q99 = np.round(center - half, 6), np.round(center + half, 6)
    return {"mean": center.tolist(), "std": [0.0] * PROPRIO_DIM, "max": (q99 + 0.1).tolist(),
            "min": (q01 - 0.1).tolist(), "q01": q01.tolist(), "q99": q99.tolist()}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("openvla_dir")
    ap.add_argument("out_dir")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    src, out = os.path.abspath(args.openvla_dir), os.path.abspath(args.out_dir)
    os.makedirs(out, exist_ok=True)
    for name in os.listdir(src):
        if name in ("dataset_statistics.json", "layout.json") or os.path.exists(os.path.join(out, name)):
            continue
        os.symlink(os.path.join(src, name), os.path.join(out, name))
    with open(os.path.join(src, "dataset_statistics.json")) as f:
        stats = json.load(f)
    for entry in stats.values():
        entry["proprio"] = proprio_stats()
    with open(os.path.join(out, "dataset_statistics.json"), "w") as f:
        json.dump(stats, f, indent=2)
    gen = torch.Generator().manual_seed(args.seed)
    for module, shapes in head_shapes().items():
        state = collections.OrderedDict(("module." + n, draw(n, s, gen)) for n, s in shapes)
        torch.save(state, os.path.join(out, f"{module}--{STEP}_checkpoint.pt"))
    n = sum(int(np.prod(s)) for shapes in head_shapes().values() for _, s in shapes)
    print(f"oft_from_openvla.py: heads of {n / 1e6:.0f} M parameters; OFT checkpoint in {out}")


if __name__ == "__main__":
    main()
