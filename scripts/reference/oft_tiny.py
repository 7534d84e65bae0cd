"""A tiny random-weight OpenVLA-OFT in the released LIBERO checkpoint layout, and its reference outputs.

usage: oft_tiny.py OUT_DIR [--seed N]

policies/tests/oft_parity.rs checks the in-process OFT port (policies/src/models/openvla/oft/) against this
model. The backbone is openvla_tiny.py's tiny Prismatic model (timm DINOv2 + SigLIP featurizers, the
fused GELU projector, transformers' Llama), here with SDPA attention, as openvla-oft's `get_vla` loads
it. What OFT adds (openvla-oft 213c5ff8, `prismatic/extern/hf/modeling_prismatic.py`
`predict_action`, `prismatic/models/{action_heads,projectors}.py`, `experiments/robot/openvla_utils.py`):

- the prompt plus 7 x 8 = 56 placeholder ids (1) and `</s>`, the placeholder embeddings zeroed;
- two images (third-person, wrist): each through the vision backbone, 2 x 256 patch tokens;
- the proprio token: ProprioProjector (fc1 Linear(8, llm), exact GELU, fc2) of the state normalised
  with the checkpoint's q01/q99 (`normalize_proprio`, BOUNDS_Q99, clipped to [-1, 1]);
- one bidirectional forward: stock transformers 4.40.1 given a 4-D all-ones attention mask computes
  what openvla-oft's transformers fork computes (SDPA with is_causal=False and no mask at batch 1);
- the readout `hidden_states[-1][:, NUM_PATCHES + NUM_PROMPT_TOKENS :][:56]`;
- L1RegressionActionHead (MLPResNet, 2 blocks) on the readout reshaped to (8, 7 x llm): the
  normalised 8 x 7 chunk, un-normalised with `0.5 (a + 1) (q99 - q01 + 1e-8) + q01` where `mask`;
- each action's gripper as OFT's LIBERO loop post-processes it: `normalize_gripper_action(binarize)`,
  then `invert_gripper_action`.

Written to OUT_DIR, as the released `moojink/openvla-7b-oft-finetuned-libero-*` repos hold them:
openvla_tiny.py's HF files (config.json, preprocessor_config.json, tokenizer files, safetensors
shards + index), dataset_statistics.json with `action` and `proprio` statistics,
`action_head--150000_checkpoint.pt` and `proprio_projector--150000_checkpoint.pt` (torch.save of
state dicts with DDP's `module.` prefix). Under OUT_DIR/reference: primary.npy and wrist.npy (224x224
RGB uint8, the images after the loop's preprocessing), state.npy (the raw 8-dim state, f64),
proprio_token.npy, readout.npy (the 56 readout hidden states), normalized.npy (8 x 7, f32),
pt_probe.pt + pt_probe_*.npy (torch.save edge cases for the Rust reader: bf16, fp16, int64, a
transposed view, a slice at an offset of a shared storage), expected.json.
"""

import argparse
import collections
import json
import os
import sys

import numpy as np
import torch
from torch import nn

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import openvla_tiny as ov  # noqa: E402
from transformers import LlamaConfig, LlamaForCausalLM  # noqa: E402

INSTRUCTION = ov.INSTRUCTION
UNNORM_KEY = ov.UNNORM_KEY
ACTION_DIM, NUM_ACTIONS_CHUNK, PROPRIO_DIM = 7, 8, 8
STOP_INDEX = 2
CHECKPOINT_STEP = 150000


class MLPResNetBlock(nn.Module):
    def __init__(self, dim):
        super().__init__()
        self.ffn = nn.Sequential(nn.LayerNorm(dim), nn.Linear(dim, dim), nn.ReLU())

    def forward(self, x):
        return x + self.ffn(x)


class MLPResNet(nn.Module):
    def __init__(self, num_blocks, input_dim, hidden_dim, output_dim):
        super().__init__()
        self.layer_norm1 = nn.LayerNorm(input_dim)
        self.fc1 = nn.Linear(input_dim, hidden_dim)
        self.relu = nn.ReLU()
        self.mlp_resnet_blocks = nn.ModuleList([MLPResNetBlock(hidden_dim) for _ in range(num_blocks)])
        self.layer_norm2 = nn.LayerNorm(hidden_dim)
        self.fc2 = nn.Linear(hidden_dim, output_dim)

    def forward(self, x):
        x = self.relu(self.fc1(self.layer_norm1(x)))
        for block in self.mlp_resnet_blocks:
            x = block(x)
        return self.fc2(self.layer_norm2(x))


class L1RegressionActionHead(nn.Module):
    def __init__(self, input_dim, hidden_dim, action_dim=ACTION_DIM):
        super().__init__()
        self.model = MLPResNet(num_blocks=2, input_dim=input_dim * ACTION_DIM, hidden_dim=hidden_dim,
                               output_dim=action_dim)

    def predict_action(self, actions_hidden_states):
        b = actions_hidden_states.shape[0]
        return self.model(actions_hidden_states.reshape(b, NUM_ACTIONS_CHUNK, -1))


class ProprioProjector(nn.Module):
    def __init__(self, llm_dim, proprio_dim):
        super().__init__()
        self.fc1 = nn.Linear(proprio_dim, llm_dim, bias=True)
        self.fc2 = nn.Linear(llm_dim, llm_dim, bias=True)
        self.act_fn1 = nn.GELU()

    def forward(self, proprio):
        return self.fc2(self.act_fn1(self.fc1(proprio)))


def randomize_head(module: nn.Module, gen: torch.Generator):
    with torch.no_grad():
        for name, p in module.named_parameters():
            if p.dim() == 1 and name.endswith("weight"):  # LayerNorm
                p.copy_(1.0 + 0.2 * torch.randn(p.shape, generator=gen))
            elif p.dim() == 1:
                p.copy_(0.1 * torch.randn(p.shape, generator=gen))
            else:
                p.copy_(torch.randn(p.shape, generator=gen) / np.sqrt(p.shape[1]))


def stats_with_proprio():
    stats = ov.norm_stats()
    rng = np.random.RandomState(11)
    # LIBERO-like state ranges: eef position, axis-angle about pi, finger joints
    center = np.array([0.0, 0.0, 1.0, 3.0, 0.0, 0.0, 0.02, -0.02])
    half = np.array([0.3, 0.3, 0.3, 0.5, 0.5, 0.5, 0.02, 0.02]) * rng.uniform(0.8, 1.2, 8)
    q01, q99 = np.round(center - half, 6), np.round(center + half, 6)
    zeros = [0.0] * PROPRIO_DIM
    stats[UNNORM_KEY]["proprio"] = {"mean": center.tolist(), "std": zeros, "max": (q99 + 0.1).tolist(),
                                    "min": (q01 - 0.1).tolist(), "q01": q01.tolist(), "q99": q99.tolist()}
    return stats


def normalize_proprio(proprio, s):
    mask = s.get("mask", np.ones_like(s["q01"], dtype=bool))
    hi, lo = np.array(s["q99"]), np.array(s["q01"])
    return np.clip(np.where(mask, 2 * (proprio - lo) / (hi - lo + 1e-8) - 1, proprio), a_min=-1.0, a_max=1.0)


def unnormalize_actions(normalized, s):
    mask = s.get("mask", np.ones_like(s["q01"], dtype=bool))
    hi, lo = np.array(s["q99"]), np.array(s["q01"])
    return np.where(mask, 0.5 * (normalized + 1) * (hi - lo + 1e-8) + lo, normalized)


def env_action(action):
    """experiments/robot/robot_utils.py: normalize_gripper_action(binarize=True), invert_gripper_action."""
    a = action.copy()
    a[..., -1] = np.sign(2 * (a[..., -1] - 0.0) / (1.0 - 0.0) - 1)
    a[..., -1] = a[..., -1] * -1.0
    return a


@torch.no_grad()
def predict(model, proprio_projector, action_head, tokenizer, images, state, instruction, stats, ref_dir):
    prompt = ov.prompt_for(instruction)
    input_ids = tokenizer(prompt, return_tensors="pt").input_ids
    if not torch.all(input_ids[:, -1] == 29871):
        input_ids = torch.cat((input_ids, torch.tensor([[29871]], dtype=torch.long)), dim=1)
    num_prompt_tokens = input_ids.shape[-1] - 1
    placeholders = torch.ones((1, ACTION_DIM * NUM_ACTIONS_CHUNK), dtype=input_ids.dtype)
    ids = torch.cat([input_ids, placeholders, torch.full((1, 1), STOP_INDEX, dtype=input_ids.dtype)], dim=-1)
    lm = model.language_model
    emb = lm.get_input_embeddings()(ids)
    actions_mask = torch.zeros(ids.shape, dtype=torch.bool)
    actions_mask[:, input_ids.shape[-1]:input_ids.shape[-1] + ACTION_DIM * NUM_ACTIONS_CHUNK] = True
    emb = emb * ~actions_mask.unsqueeze(-1)
    # the vision backbone once per image; patches concatenated along the sequence
    pixel_values = torch.cat([ov.pixel_values_of(img) for img in images], dim=1)
    patches = torch.cat([model.vision(pv) for pv in torch.split(pixel_values, 6, dim=1)], dim=1)
    projected = model.project(patches)
    proprio = normalize_proprio(state, stats[UNNORM_KEY]["proprio"])
    proprio_t = torch.Tensor(proprio).to(projected.dtype)
    proprio_token = proprio_projector(proprio_t.reshape(1, -1)).unsqueeze(1)
    projected = torch.cat((projected, proprio_token), dim=1)
    num_patches = projected.shape[1]
    mm = torch.cat([emb[:, :1], projected, emb[:, 1:]], dim=1)
    t = mm.shape[1]
    out = lm(inputs_embeds=mm, attention_mask=torch.ones((1, 1, t, t)), output_hidden_states=True)
    causal = lm(inputs_embeds=mm, output_hidden_states=True)
    hidden = out.hidden_states[-1]
    start = num_patches + num_prompt_tokens
    readout = hidden[:, start:start + ACTION_DIM * NUM_ACTIONS_CHUNK]
    # bidirectional: early positions see the later ones (a causal forward gives other values there)
    gap = float((hidden[:, :start] - causal.hidden_states[-1][:, :start]).abs().max())
    assert gap > 1e-3, f"the 4-D mask did not make attention bidirectional ({gap})"
    normalized = action_head.predict_action(readout).reshape(NUM_ACTIONS_CHUNK, ACTION_DIM).float().numpy()
    actions = unnormalize_actions(normalized, stats[UNNORM_KEY]["action"])
    env = env_action(actions)
    np.save(os.path.join(ref_dir, "proprio_token.npy"), proprio_token[0, 0].float().numpy())
    np.save(os.path.join(ref_dir, "readout.npy"), readout[0].float().numpy())
    np.save(os.path.join(ref_dir, "normalized.npy"), normalized)
    expected = {
        "instruction": instruction, "prompt": prompt, "unnorm_key": UNNORM_KEY,
        "input_ids": input_ids[0].tolist(), "num_prompt_tokens": num_prompt_tokens, "num_patches": num_patches,
        "sequence_length": t, "bidirectional_vs_causal_max_abs": gap,
        "proprio_normalized": proprio.tolist(), "actions": actions.tolist(), "env_actions": env.tolist(),
        "versions": {"torch": torch.__version__, "transformers": sys.modules["transformers"].__version__},
    }
    with open(os.path.join(ref_dir, "expected.json"), "w") as f:
        json.dump(expected, f, indent=2)
    return expected


def save_pt_probe(ref_dir: str, gen: torch.Generator):
    """torch.save cases the Rust reader must handle, with their values as f32 .npy."""
    base = torch.randn(6, 5, generator=gen)
    probe = collections.OrderedDict()
    probe["bf16"] = torch.randn(3, 4, generator=gen).to(torch.bfloat16)
    probe["fp16"] = torch.randn(5, generator=gen).to(torch.float16)
    probe["int64"] = torch.arange(-3, 9).reshape(3, 4)
    probe["transposed"] = base.t()
    probe["offset_slice"] = base[2:4, 1:]
    probe["scalar"] = torch.tensor(2.5)
    torch.save(probe, os.path.join(ref_dir, "pt_probe.pt"))
    for k, v in probe.items():
        np.save(os.path.join(ref_dir, f"pt_probe_{k}.npy"), np.ascontiguousarray(v.to(torch.float32).numpy()))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("out_dir")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    torch.manual_seed(args.seed)
    torch.set_num_threads(1)
    out_dir, ref_dir = args.out_dir, os.path.join(args.out_dir, "reference")
    os.makedirs(ref_dir, exist_ok=True)
    tokenizer = ov.build_tokenizer(out_dir)
    model = ov.TinyOpenVLA()
    # openvla-oft's get_vla loads the default (SDPA) attention, the implementation its fork patches
    model.language_model = LlamaForCausalLM(LlamaConfig(**ov.LLM, attn_implementation="sdpa"))
    model.eval()
    gen = torch.Generator().manual_seed(args.seed)
    ov.randomize(model, gen)
    llm_dim = ov.LLM["hidden_size"]
    proprio_projector = ProprioProjector(llm_dim, PROPRIO_DIM).eval()
    action_head = L1RegressionActionHead(llm_dim, llm_dim).eval()
    randomize_head(proprio_projector, gen)
    randomize_head(action_head, gen)
    stats = stats_with_proprio()
    ov.save_checkpoint(model, out_dir, stats)
    for name, module in (("action_head", action_head), ("proprio_projector", proprio_projector)):
        # saved from DDP in training: every key under `module.`
        state = collections.OrderedDict(("module." + k, v) for k, v in module.state_dict().items())
        torch.save(state, os.path.join(out_dir, f"{name}--{CHECKPOINT_STEP}_checkpoint.pt"))
    rng = np.random.RandomState(args.seed + 1)
    images = [rng.randint(0, 256, (224, 224, 3)).astype(np.uint8) for _ in range(2)]
    np.save(os.path.join(ref_dir, "primary.npy"), images[0])
    np.save(os.path.join(ref_dir, "wrist.npy"), images[1])
    # a LIBERO-like state; the 4th dimension beyond q99 so that the clip is exercised
    state = np.array([0.05, -0.1, 1.1, 3.7, 0.05, -0.1, 0.035, -0.035], dtype=np.float64)
    np.save(os.path.join(ref_dir, "state.npy"), state)
    expected = predict(model, proprio_projector, action_head, tokenizer, images, state, INSTRUCTION, stats, ref_dir)
    save_pt_probe(ref_dir, gen)
    print(json.dumps({k: expected[k] for k in ("env_actions", "bidirectional_vs_causal_max_abs")}))


if __name__ == "__main__":
    main()
