"""OpenVLA-7B's checkpoint without its weights, for a machine that has torch but neither
transformers nor timm (the GPU machine), and too little room to carry 15 GB of weights.

usage: openvla_layout.py OUT_DIR

Built on the meta device from openvla_bench.py's architecture (openvla_tiny.TinyOpenVLA at the
released sizes), OUT_DIR gets what openvla_bench.py writes beside the shards (config.json,
dataset_statistics.json, preprocessor_config.json, the tokenizer files) and layout.json: every
tensor's name and shape with the random initialisation of openvla_tiny.randomize as (mean, std),
and the lm_head rows it scales. `fill_random_weights.py OUT_DIR` then writes the bf16 shards and
their index with torch and safetensors alone. The weights are random (as in openvla_bench.py):
for speed and memory figures, not for success rates.
"""

import json
import os
import sys

import numpy as np
import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import openvla_tiny as tiny  # noqa: E402
from openvla_bench import LLM_7B  # noqa: E402


def init_of(name: str, shape) -> tuple:
    """(mean, std) of openvla_tiny.randomize for one tensor."""
    if len(shape) == 1 and ("norm" in name or name.endswith("scale_factor")):
        return 1.0, 0.2
    if len(shape) == 1:
        return 0.0, 0.1
    if name.endswith("embed_tokens.weight"):
        return 0.0, 1.0
    fan_in = shape[1] if len(shape) == 2 else int(np.prod(shape[1:]))
    return 0.0, (1.0 / np.sqrt(fan_in) if len(shape) in (2, 4) else 0.5)


def main():
    out_dir = sys.argv[1]
    os.makedirs(out_dir, exist_ok=True)
    tiny.build_tokenizer(out_dir)
    # The 6.7 B of Llama-2 on the meta device (shapes only); timm's towers cannot be built there
    # (their init reads values), so they are built on the host (0.7 B parameters in bf16).
    llama = tiny.LlamaForCausalLM

    def llama_on_meta(config):
        with torch.device("meta"):
            return llama(config)

    tiny.LlamaForCausalLM = llama_on_meta
    torch.set_default_dtype(torch.bfloat16)
    model = tiny.TinyOpenVLA(dino_kw={}, siglip_kw={}, llm_kw=LLM_7B).eval()
    torch.set_default_dtype(torch.float32)
    tensors = []
    for name, t in sorted(model.state_dict().items()):
        mean, std = init_of(name, list(t.shape))
        tensors.append({"name": name, "shape": list(t.shape), "mean": mean, "std": float(std)})
    layout = {
        "dtype": "bfloat16",
        "shards": 4,
        "tensors": tensors,
        # as openvla_tiny.randomize: greedy decoding lands on action bins, as a trained OpenVLA's does
        "scale_rows": {"name": "language_model.lm_head.weight", "rows": [32000 - tiny.N_ACTION_BINS, 32000], "by": 3.0},
    }
    with open(os.path.join(out_dir, "layout.json"), "w") as f:
        json.dump(layout, f)
    tiny.save_configs(model, out_dir, tiny.norm_stats(), timm_kwargs=None)
    n = sum(int(np.prod(t["shape"])) for t in tensors)
    print(f"openvla_layout.py: {len(tensors)} tensors, {n / 1e9:.2f} B parameters, written to {out_dir}")


if __name__ == "__main__":
    main()
