"""OpenVLA-OFT's 7B architecture with random bf16 weights on the GPU: the checkpoint for the Rust bench,
and the Python reference forward's per-chunk latency and batched throughput.

usage: oft_bench.py OUT_DIR [--batch 1,8,32] [--iters 10] [--warmup 2] [--json OUT.json]

Weights cannot be downloaded here, so the full-size run uses the architecture of
`moojink/openvla-7b-oft-finetuned-libero-*`: openvla_bench.py's 7B OpenVLA (DINOv2 ViT-L + SigLIP
so400m, Llama-2-7B) with SDPA attention, the attention openvla-oft's `get_vla` loads, plus
oft_tiny.py's `L1RegressionActionHead` and `ProprioProjector` at the LLM's width (4096), all random
in bf16. Written to OUT_DIR in the released layout (HF safetensors shards, `dataset_statistics.json`
with action and proprio statistics, `action_head--150000_checkpoint.pt`,
`proprio_projector--150000_checkpoint.pt` with DDP's `module.` prefix), and under OUT_DIR/reference
the B = 1 prediction (primary.npy, wrist.npy, state.npy, normalized.npy, expected.json) for the Rust
bench to compare with.

One timed call, as in policies/benches/openvla.rs with `--oft`: the vision tower on 2B images
(third-person, wrist), the proprio projector on B states, one bidirectional forward of B left-padded
sequences (`[<s>] [512 patches] [proprio] [prompt] [56 zeroed placeholders] [</s>]`, LIBERO
instructions of different lengths; a 4-D mask that hides each row's padding, which at B = 1 is
oft_tiny.py's all-ones mask), the L1 head on each row's 56 readout states, the 8 x 7 chunks read back
to the host. transformers 4.40.1's LlamaForCausalLM with SDPA, torch.no_grad, CUDA synchronised
around each call.
"""

import collections
import json
import os
import sys
import time

import numpy as np
import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import oft_tiny as oft  # noqa: E402
import openvla_bench as ovb  # noqa: E402
import openvla_tiny as tiny  # noqa: E402
from transformers.models.llama.modeling_llama import LlamaAttention, LlamaSdpaAttention  # noqa: E402

CHUNK = oft.ACTION_DIM * oft.NUM_ACTIONS_CHUNK


@torch.no_grad()
def predict_batch(model, proprio_projector, action_head, tokenizer, images, states, instructions, stats):
    """OFT's predict_action on B queries in one forward; returns (normalized [B, 8, 7] f32 on the host,
    readout [B, 56, hidden])."""
    lm = model.language_model
    dev, dtype = next(model.parameters()).device, next(model.parameters()).dtype
    rows = []
    for instruction in instructions:
        ids = tokenizer(tiny.prompt_for(instruction)).input_ids
        if ids[-1] != 29871:
            ids.append(29871)
        rows.append(ids)
    # (primary, wrist) per query, each through the vision backbone: [B, 2 x 256, hidden]
    pixel_values = torch.cat([tiny.pixel_values_of(im) for pair in images for im in pair]).to(dev, dtype)
    projected = model.project(model.vision(pixel_values))
    b = len(rows)
    projected = projected.reshape(b, -1, projected.shape[-1])
    proprio = np.stack([oft.normalize_proprio(s, stats[tiny.UNNORM_KEY]["proprio"]) for s in states])
    proprio_token = proprio_projector(torch.Tensor(proprio).to(dev, projected.dtype)).unsqueeze(1)
    projected = torch.cat((projected, proprio_token), dim=1)
    num_patches = projected.shape[1]
    longest = max(len(r) for r in rows) + num_patches + CHUNK + 1
    embeds, keep, starts = [], [], []
    for r, ids in enumerate(rows):
        n = len(ids)
        all_ids = torch.tensor(ids + [1] * CHUNK + [oft.STOP_INDEX], device=dev)
        emb = lm.get_input_embeddings()(all_ids)
        emb[n:n + CHUNK] = 0
        row = torch.cat([emb[:1], projected[r], emb[1:]], dim=0)
        pad = longest - row.shape[0]
        embeds.append(torch.cat([row.new_zeros(pad, row.shape[1]), row], dim=0))
        keep.append([0] * pad + [1] * row.shape[0])
        starts.append(pad + num_patches + n - 1)
    keep = torch.tensor(keep, device=dev)
    mask = keep[:, None, None, :].expand(b, 1, longest, longest)
    position_ids = (keep.cumsum(-1) - 1).masked_fill_(keep == 0, 1)
    out = lm(inputs_embeds=torch.stack(embeds), attention_mask=mask, position_ids=position_ids,
             output_hidden_states=True)
    hidden = out.hidden_states[-1]
    readout = torch.stack([hidden[r, s:s + CHUNK] for r, s in enumerate(starts)])
    normalized = action_head.predict_action(readout).reshape(b, oft.NUM_ACTIONS_CHUNK, oft.ACTION_DIM)
    return normalized.float().cpu().numpy(), readout


def set_attention(model, implementation):
    """transformers' eager or SDPA attention on the built model: the two classes share their
    parameters (LlamaSdpaAttention only overrides forward), and the mask preparation reads
    config._attn_implementation."""
    cls = {"sdpa": LlamaSdpaAttention, "eager": LlamaAttention}[implementation]
    for layer in model.language_model.model.layers:
        layer.self_attn.__class__ = cls
    model.language_model.config._attn_implementation = implementation


def build(out_dir):
    """The 7B OFT model on the GPU in bf16, saved to out_dir in the released layout."""
    torch.manual_seed(0)
    tokenizer = tiny.build_tokenizer(out_dir)
    llm_dim = ovb.LLM_7B["hidden_size"]
    torch.set_default_dtype(torch.bfloat16)
    with torch.device("cuda"):
        model = tiny.TinyOpenVLA(dino_kw={}, siglip_kw={}, llm_kw=ovb.LLM_7B).eval()
        proprio_projector = oft.ProprioProjector(llm_dim, oft.PROPRIO_DIM).eval()
        action_head = oft.L1RegressionActionHead(llm_dim, llm_dim).eval()
    torch.set_default_dtype(torch.float32)
    # SDPA attention, as openvla-oft's get_vla loads it
    set_attention(model, "sdpa")
    tiny.randomize(model, torch.Generator(device="cuda").manual_seed(0))
    gen = torch.Generator().manual_seed(1)
    oft.randomize_head(proprio_projector, gen)
    oft.randomize_head(action_head, gen)
    n_params = sum(p.numel() for m in (model, proprio_projector, action_head) for p in m.parameters())
    stats = oft.stats_with_proprio()
    tiny.save_checkpoint(model, out_dir, stats, n_shards=4, timm_kwargs=None)
    for name, module in (("action_head", action_head), ("proprio_projector", proprio_projector)):
        state = collections.OrderedDict(("module." + k, v.cpu()) for k, v in module.state_dict().items())
        torch.save(state, os.path.join(out_dir, f"{name}--{oft.CHECKPOINT_STEP}_checkpoint.pt"))
    return model, proprio_projector, action_head, tokenizer, stats, n_params


def main():
    args, ref_dir = ovb.bench_args()
    t0 = time.perf_counter()
    model, proprio_projector, action_head, tokenizer, stats, n_params = build(args.out_dir)
    build_s = time.perf_counter() - t0

    # the B = 1 reference: two images, a LIBERO-like state, the instruction
    rng = np.random.RandomState(1)
    primary, wrist = (rng.randint(0, 256, (224, 224, 3)).astype(np.uint8) for _ in range(2))
    state = np.array([0.05, -0.1, 1.1, 3.7, 0.05, -0.1, 0.035, -0.035], dtype=np.float64)
    normalized, _ = predict_batch(model, proprio_projector, action_head, tokenizer, [(primary, wrist)], [state],
                                  [tiny.INSTRUCTION], stats)
    for name, value in (("primary", primary), ("wrist", wrist), ("state", state), ("normalized", normalized[0])):
        np.save(os.path.join(ref_dir, f"{name}.npy"), value)
    expected = {"instruction": tiny.INSTRUCTION, "unnorm_key": tiny.UNNORM_KEY, "dtype": "torch.bfloat16",
                "attention": "sdpa", "normalized": normalized[0].tolist()}
    with open(os.path.join(ref_dir, "expected.json"), "w") as f:
        json.dump(expected, f, indent=2)
    print(f"oft_bench.py: {n_params / 1e9:.2f} B parameters in bf16 on {torch.cuda.get_device_name()}; "
          f"built and written in {build_s:.1f} s; B=1 chunk[0] {np.round(normalized[0, 0], 4).tolist()}", flush=True)

    rows = []
    for b in [int(x) for x in args.batch.split(",")]:
        rng = np.random.RandomState(b)
        images = [tuple(rng.randint(0, 256, (224, 224, 3)).astype(np.uint8) for _ in range(2)) for _ in range(b)]
        states = [state + rng.uniform(-0.05, 0.05, state.shape) for _ in range(b)]
        instructions = [ovb.INSTRUCTIONS[i % len(ovb.INSTRUCTIONS)] for i in range(b)]
        row = ovb.timed_row(
            lambda: predict_batch(model, proprio_projector, action_head, tokenizer, images, states, instructions, stats),
            b, args, unit="query", actions_per_query=oft.NUM_ACTIONS_CHUNK)
        rows.append(row)
    # the B = 1 reference again with eager attention: the Rust side's eager pass must match it bit for
    # bit (the same kernels), which checks everything apart from the attention kernel
    set_attention(model, "eager")
    eager, _ = predict_batch(model, proprio_projector, action_head, tokenizer, [(primary, wrist)], [state],
                             [tiny.INSTRUCTION], stats)
    np.save(os.path.join(ref_dir, "normalized_eager.npy"), eager[0])
    print(f"  eager attention at B=1: chunk max |eager - sdpa| {float(np.abs(eager[0] - normalized[0]).max()):.4f}")
    report = {"implementation": "python (transformers LlamaForCausalLM sdpa + timm, openvla-oft's head classes)",
              "versions": {"torch": torch.__version__, "transformers": sys.modules["transformers"].__version__,
                           "timm": sys.modules["timm"].__version__},
              "device": torch.cuda.get_device_name(), "dtype": "bfloat16", "parameters": n_params,
              "build_s": build_s, "results": rows}
    if args.json:
        with open(args.json, "w") as f:
            json.dump(report, f, indent=2)


if __name__ == "__main__":
    main()
