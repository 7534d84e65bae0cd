"""OpenVLA's 7B architecture with random bf16 weights on the GPU: the checkpoint for the Rust bench,
and the Python reference forward's per-action latency and batched throughput.

usage: openvla_bench.py OUT_DIR [--batch 1,8,32] [--iters 10] [--warmup 2] [--json OUT.json]

Weights cannot be downloaded here, so the full-size run uses the architecture of
`openvla/openvla-7b` (scripts/reference/openvla_tiny.py's TinyOpenVLA at the real sizes: timm's
vit_large_patch14_reg4_dinov2 and vit_so400m_patch14_siglip_224 with their default sizes,
Llama-2-7B's 4096 x 32 layers, vocabulary 32064) with random weights in bf16. Written to OUT_DIR:
the checkpoint in the Hugging Face layout (bf16 safetensors shards), the tiny Llama-2-shaped
tokenizer (prompt lengths are those of whole-word tokens, close to Llama-2's on LIBERO
instructions), and under OUT_DIR/reference the B = 1 prediction (image, tokens, step logits) for
the Rust bench to compare with.

One timed call, as in policies/benches/openvla.rs: the fused vision tower on B images, the prefill
of B left-padded prompts (LIBERO instructions of different lengths, transformers' attention mask
and position ids), 7 greedy decode steps with the KV cache, the tokens read back to the host after
each. transformers' LlamaForCausalLM with eager attention (the arithmetic the Rust port
reproduces), torch.no_grad, CUDA synchronised around each call.
"""

import argparse
import json
import os
import sys
import time

import numpy as np
import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import openvla_tiny as tiny  # noqa: E402

LLM_7B = dict(
    vocab_size=32064, hidden_size=4096, intermediate_size=11008, num_hidden_layers=32, num_attention_heads=32,
    num_key_value_heads=32, max_position_embeddings=2048, rms_norm_eps=1e-6, rope_theta=10000.0,
    pad_token_id=32000, bos_token_id=1, eos_token_id=2, tie_word_embeddings=False,
)
# The same instructions as policies/benches/openvla.rs.
INSTRUCTIONS = [
    "pick up the black bowl between the plate and the ramekin and place it on the plate",
    "pick up the alphabet soup and place it in the basket",
    "open the middle drawer of the cabinet",
    "put both the alphabet soup and the tomato sauce in the basket",
]
ACTION_DIM = 7


@torch.no_grad()
def predict_batch(model, tokenizer, pixel_values, instructions):
    lm = model.language_model
    rows = []
    for b, instruction in enumerate(instructions):
        ids = tokenizer(tiny.prompt_for(instruction), return_tensors="pt").input_ids[0].tolist()
        if ids[-1] != 29871:
            ids.append(29871)
        rows.append(ids)
    projected = model.project(model.vision(pixel_values))
    dev, n_patches = projected.device, projected.shape[1]
    longest = max(len(r) for r in rows) + n_patches
    embeds, mask = [], []
    for b, ids in enumerate(rows):
        emb = lm.get_input_embeddings()(torch.tensor(ids, device=dev))
        row = torch.cat([emb[:1], projected[b], emb[1:]], dim=0)
        pad = longest - row.shape[0]
        embeds.append(torch.cat([row.new_zeros(pad, row.shape[1]), row], dim=0))
        mask.append([0] * pad + [1] * row.shape[0])
    attention_mask = torch.tensor(mask, device=dev)
    position_ids = (attention_mask.cumsum(-1) - 1).masked_fill_(attention_mask == 0, 1)
    out = lm(inputs_embeds=torch.stack(embeds), attention_mask=attention_mask, position_ids=position_ids, use_cache=True)
    tokens = []
    for step in range(ACTION_DIM):
        tok = out.logits[:, -1].float().argmax(-1)
        tokens.append(tok.tolist())
        if step + 1 < ACTION_DIM:
            attention_mask = torch.cat([attention_mask, attention_mask.new_ones(len(rows), 1)], dim=1)
            position_ids = position_ids[:, -1:] + 1
            out = lm(input_ids=tok[:, None], attention_mask=attention_mask, position_ids=position_ids,
                     past_key_values=out.past_key_values, use_cache=True)
    return tokens


def bench_args():
    """The command line of the 7B benches (this one and oft_bench.py); the reference folder made."""
    ap = argparse.ArgumentParser()
    ap.add_argument("out_dir")
    ap.add_argument("--batch", default="1,8,32")
    ap.add_argument("--iters", type=int, default=10)
    ap.add_argument("--warmup", type=int, default=2)
    ap.add_argument("--json")
    args = ap.parse_args()
    assert torch.cuda.is_available(), "the 7B bench runs on a CUDA GPU"
    ref_dir = os.path.join(args.out_dir, "reference")
    os.makedirs(ref_dir, exist_ok=True)
    return args, ref_dir


def timed_row(call, b, args, unit="action", actions_per_query=1):
    """`call()` on B queries, timed args.iters times after args.warmup, CUDA synchronised around
    each: the result row (median, p90, min; per query; actions/s), printed."""
    times = []
    for i in range(args.warmup + args.iters):
        torch.cuda.synchronize()
        t = time.perf_counter()
        call()
        torch.cuda.synchronize()
        if i >= args.warmup:
            times.append(time.perf_counter() - t)
    times.sort()
    med, p90 = times[len(times) // 2], times[round((len(times) - 1) * 0.9)]
    actions = b * actions_per_query
    chunk = f" ({actions_per_query} per {unit})" if actions_per_query > 1 else ""
    print(f"  B={b:>3}: {med * 1e3:>8.1f} ms per call (p90 {p90 * 1e3:.1f}), {med * 1e3 / b:>7.2f} ms per {unit}, "
          f"{actions / med:>7.1f} actions/s{chunk}", flush=True)
    return {"batch": b, "iters": len(times), "call_ms_median": med * 1e3, "call_ms_p90": p90 * 1e3,
            "call_ms_min": times[0] * 1e3, f"ms_per_{unit}": med * 1e3 / b, "actions_per_s": actions / med}


def main():
    args, ref_dir = bench_args()
    out_dir = args.out_dir
    t0 = time.perf_counter()
    torch.manual_seed(0)
    tokenizer = tiny.build_tokenizer(out_dir)
    torch.set_default_dtype(torch.bfloat16)
    with torch.device("cuda"):
        model = tiny.TinyOpenVLA(dino_kw={}, siglip_kw={}, llm_kw=LLM_7B).eval()
    torch.set_default_dtype(torch.float32)
    tiny.randomize(model, torch.Generator(device="cuda").manual_seed(0))
    n_params = sum(p.numel() for p in model.parameters())
    build_s = time.perf_counter() - t0
    stats = tiny.norm_stats()
    t0 = time.perf_counter()
    tiny.save_checkpoint(model, out_dir, stats, n_shards=4, timm_kwargs=None)
    save_s = time.perf_counter() - t0
    image = np.random.RandomState(1).randint(0, 256, (224, 224, 3)).astype(np.uint8)
    np.save(os.path.join(ref_dir, "image.npy"), image)
    expected = tiny.predict(model, tokenizer, image, tiny.INSTRUCTION, stats, ref_dir)
    print(f"openvla_bench.py: {n_params / 1e9:.2f} B parameters in bf16 on {torch.cuda.get_device_name()}; "
          f"built in {build_s:.1f} s, checkpoint written in {save_s:.1f} s; B=1 tokens {expected['tokens']}", flush=True)

    rows = []
    for b in [int(x) for x in args.batch.split(",")]:
        rng = np.random.RandomState(b)
        images = [rng.randint(0, 256, (224, 224, 3)).astype(np.uint8) for _ in range(b)]
        instructions = [INSTRUCTIONS[i % len(INSTRUCTIONS)] for i in range(b)]
        row = timed_row(lambda: predict_batch(
            model, tokenizer, torch.cat([tiny.pixel_values_of(im) for im in images]).to("cuda", torch.bfloat16),
            instructions), b, args)
        rows.append(row)
    report = {"implementation": "python (transformers LlamaForCausalLM eager + timm)",
              "versions": {"torch": torch.__version__, "transformers": sys.modules["transformers"].__version__,
                           "timm": sys.modules["timm"].__version__},
              "device": torch.cuda.get_device_name(), "dtype": "bfloat16", "parameters": n_params,
              "build_s": build_s, "save_s": save_s, "results": rows}
    if args.json:
        with open(args.json, "w") as f:
            json.dump(report, f, indent=2)


if __name__ == "__main__":
    main()
