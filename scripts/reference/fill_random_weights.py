"""Write the random weights of a checkpoint layout (openvla_layout.py's layout.json) as safetensors
shards and their index, with torch and safetensors only (what the GPU machine has).

usage: fill_random_weights.py DIR [--device cuda|cpu] [--seed 0]

Each tensor is mean + std * N(0, 1) in the layout's dtype, drawn on --device from one seeded
generator in the layout's order; the layout's scale_rows multiplies the rows it names.
"""

import argparse
import json
import os
import time

import torch
from safetensors.torch import save_file


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("dir")
    ap.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    t0 = time.perf_counter()
    with open(os.path.join(args.dir, "layout.json")) as f:
        layout = json.load(f)
    dtype = getattr(torch, layout["dtype"])
    gen = torch.Generator(device=args.device).manual_seed(args.seed)
    tensors = layout["tensors"]
    per = -(-len(tensors) // layout["shards"])
    shards = [tensors[i:i + per] for i in range(0, len(tensors), per)]
    scale = layout.get("scale_rows")
    weight_map, total = {}, 0
    for i, shard in enumerate(shards):
        fname = f"model-{i + 1:05d}-of-{len(shards):05d}.safetensors"
        out = {}
        for t in shard:
            x = torch.randn(t["shape"], generator=gen, device=args.device, dtype=dtype) * t["std"] + t["mean"]
            if scale and scale["name"] == t["name"]:
                lo, hi = scale["rows"]
                x[lo:hi] *= scale["by"]
            out[t["name"]] = x.to("cpu").contiguous()
            weight_map[t["name"]] = fname
            total += x.numel() * x.element_size()
        save_file(out, os.path.join(args.dir, fname), metadata={"format": "pt"})
        del out
    with open(os.path.join(args.dir, "model.safetensors.index.json"), "w") as f:
        json.dump({"metadata": {"total_size": total}, "weight_map": weight_map}, f, indent=2)
    print(f"fill_random_weights.py: {total / 1e9:.1f} GB in {len(shards)} shards in {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
