"""A tiny random-weight OpenVLA, saved as a Hugging Face checkpoint, and its reference outputs.

usage: openvla_tiny.py OUT_DIR [--seed N]

The in-process OpenVLA port (policies/src/models/openvla/) cannot be tested on the real 7B weights here, so
policies/tests/openvla_parity.rs checks it against this model instead: the same Prismatic
architecture as `openvla/openvla-7b` and its LIBERO fine-tunes, built from the same library layer
types, only narrow and shallow:

- the fused vision backbone: timm's `vit_large_patch14_reg4_dinov2` and `vit_so400m_patch14_siglip_224`
  model functions (class token + 4 register tokens + LayerScale; no class token + MAP head), created
  as OpenVLA's PrismaticVisionBackbone creates them (`num_classes=0`, `img_size=224`) with smaller
  `embed_dim`/`depth`/`num_heads`, with the same two patches OpenVLA applies: `forward` returns
  `get_intermediate_layers(n={depth - 2})[0]` (the second-to-last block's patch tokens, no final norm),
  and LayerScale's `gamma` renamed `scale_factor`. Patch features are concatenated along channels.
- the fused GELU MLP projector: Linear(d, 4d) -> GELU -> Linear(4d, llm) -> GELU -> Linear(llm, llm).
- transformers' LlamaForCausalLM with Llama-2's vocabulary size padded to 32064 (OpenVLA's
  `pad_to_multiple_of=64`), so that the action tokens are the real ones: the last 256 ids below 32000.
- a Llama-2-style tokenizer.json (BPE with byte fallback, `▁` prefix normalizer, `<s>` template) with
  Llama-2's special ids (`<unk>` 0, `<s>` 1, `</s>` 2, bytes 3..258, `▁` = 29871, `<PAD>` = 32000) but
  a small vocabulary made for LIBERO instructions.

Written to OUT_DIR: config.json (OpenVLAConfig's fields, norm_stats included), preprocessor_config.json,
dataset_statistics.json, tokenizer.json + tokenizer_config.json + special_tokens_map.json,
model-0000k-of-00002.safetensors + model.safetensors.index.json (float32), and under OUT_DIR/reference:
image.npy (the 224x224 RGB uint8 input), input_ids.npy, pixel_values.npy, patch_features.npy,
projected.npy, step_logits.npy (the last position's logits before each of the 7 greedy tokens),
and expected.json (instruction, prompt, token ids, bin indices, normalized and unnormalized action).

The reference side follows OpenVLA's `predict_action`: prompt "In: What action should the robot take
to {instruction.lower()}?\nOut:", token 29871 appended when the prompt does not end with it, the image
inserted after <s>, greedy decoding of action_dim tokens with a KV cache, `vocab_size - token - 1`
clipped to the 255 bin centers of linspace(-1, 1, 256), unnormalized with q01/q99 where `mask`.
"""

import argparse
import json
import os
import sys
from functools import partial

import numpy as np
import timm
import torch
from safetensors.torch import save_file
from timm.models.vision_transformer import LayerScale
from tokenizers import Tokenizer, decoders, normalizers, processors
from tokenizers.models import BPE
from transformers import LlamaConfig, LlamaForCausalLM, LlamaTokenizerFast

INSTRUCTION = "Pick up the black bowl between the plate and the ramekin and place it on the plate"
UNNORM_KEY = "libero_spatial_no_noops"
DINO_ID, SIGLIP_ID = "vit_large_patch14_reg4_dinov2.lvd142m", "vit_so400m_patch14_siglip_224"
# The tiny sizes (the real ones: DINOv2 ViT-L 1024/24/16, SigLIP so400m 1152/27/16).
DINO_KW = dict(embed_dim=48, depth=4, num_heads=3)
SIGLIP_KW = dict(embed_dim=64, depth=3, num_heads=4)
LLM = dict(
    vocab_size=32064, hidden_size=64, intermediate_size=172, num_hidden_layers=2, num_attention_heads=4,
    num_key_value_heads=2, max_position_embeddings=2048, rms_norm_eps=1e-5, rope_theta=10000.0,
    pad_token_id=32000, bos_token_id=1, eos_token_id=2, tie_word_embeddings=False,
)
N_ACTION_BINS, PAD_TO_MULTIPLE_OF = 256, 64
# OpenVLA-7B's preprocessor_config.json: DINOv2 (ImageNet) and SigLIP normalizations; the transform
# uses tvf_normalize_params (ImageNet's values rounded as the released file has them).
TVF_NORMALIZE = [
    {"inplace": False, "mean": [0.484375, 0.455078125, 0.40625], "std": [0.228515625, 0.2236328125, 0.224609375]},
    {"inplace": False, "mean": [0.5, 0.5, 0.5], "std": [0.5, 0.5, 0.5]},
]


def prompt_for(instruction: str) -> str:
    return f"In: What action should the robot take to {instruction.lower()}?\nOut:"


def build_tokenizer(out_dir: str) -> LlamaTokenizerFast:
    """A Llama-2-shaped tokenizer with a small merge table (whole words of LIBERO's instructions)."""
    vocab = {"<unk>": 0, "<s>": 1, "</s>": 2}
    for b in range(256):
        vocab[f"<0x{b:02X}>"] = 3 + b
    vocab["▁"] = 29871
    words = (
        "in what action should the robot take to pick up black bowl between plate and ramekin place it on "
        "out open close drawer put cabinet stove turn top of wine bottle cream cheese basket next cookie box "
        "from table center tray wooden alphabet soup tomato sauce ketchup butter milk orange juice salad "
        "dressing bbq chocolate pudding mug microwave frying pan left right front back middle"
    ).split() + ["In", "What", "Out"]
    merges, next_id = [], 259
    alphabet = sorted({c for w in words for c in w} | set(":?"))
    for c in alphabet:
        vocab[c] = next_id
        next_id += 1
    for w in words:
        cur = "▁"
        for c in w:
            new = cur + c
            if new not in vocab:
                vocab[new] = next_id
                next_id += 1
                merges.append((cur, c))
            cur = new
    while next_id < 32000:  # fill to Llama-2's 32000 ids (never produced by a merge)
        if next_id != 29871:
            vocab[f"<unused{next_id}>"] = next_id
        next_id += 1
    model = BPE(vocab=vocab, merges=merges, unk_token="<unk>", fuse_unk=True, byte_fallback=True)
    tok = Tokenizer(model)
    tok.normalizer = normalizers.Sequence([normalizers.Prepend("▁"), normalizers.Replace(" ", "▁")])
    tok.decoder = decoders.Sequence(
        [decoders.Replace("▁", " "), decoders.ByteFallback(), decoders.Fuse(), decoders.Strip(" ", 1, 0)]
    )
    tok.post_processor = processors.TemplateProcessing(single="<s> $A", pair="<s> $A <s> $B", special_tokens=[("<s>", 1)])
    tok.add_special_tokens(["<unk>", "<s>", "</s>"])
    tok.add_special_tokens(["<PAD>"])
    assert tok.token_to_id("<PAD>") == 32000
    tok.save(os.path.join(out_dir, "tokenizer.json"))
    with open(os.path.join(out_dir, "tokenizer_config.json"), "w") as f:
        json.dump({"tokenizer_class": "LlamaTokenizer", "add_bos_token": True, "add_eos_token": False,
                   "bos_token": "<s>", "eos_token": "</s>", "unk_token": "<unk>", "pad_token": "<PAD>",
                   "model_max_length": 2048, "padding_side": "right", "legacy": False}, f, indent=2)
    with open(os.path.join(out_dir, "special_tokens_map.json"), "w") as f:
        json.dump({"bos_token": "<s>", "eos_token": "</s>", "unk_token": "<unk>", "pad_token": "<PAD>"}, f, indent=2)
    return LlamaTokenizerFast.from_pretrained(out_dir)


def _ls_forward(self, x):
    return x * self.scale_factor


def make_featurizer(timm_id: str, kw: dict) -> torch.nn.Module:
    """timm model as OpenVLA's PrismaticVisionBackbone makes it, with its two patches."""
    model = timm.create_model(timm_id.split(".")[0], pretrained=False, num_classes=0, img_size=224,
                              act_layer=None, **kw)
    n = {len(model.blocks) - 2}

    def forward(x):
        out = model.get_intermediate_layers(x, n=n)
        return out[0] if isinstance(out, tuple) else out

    model.forward = forward
    for m in model.modules():
        if isinstance(m, LayerScale):
            m.scale_factor = torch.nn.Parameter(m.gamma.clone())
            m.forward = _ls_forward.__get__(m, LayerScale)
            del m.gamma
    return model


class TinyOpenVLA(torch.nn.Module):
    """The Prismatic architecture at the tiny sizes above, or at any others (openvla_bench.py builds
    the full 7B one with the timm defaults and Llama-2-7B's sizes)."""

    def __init__(self, dino_kw=DINO_KW, siglip_kw=SIGLIP_KW, llm_kw=LLM):
        super().__init__()
        self.vision_backbone = torch.nn.Module()
        self.vision_backbone.featurizer = make_featurizer(DINO_ID, dino_kw)
        self.vision_backbone.fused_featurizer = make_featurizer(SIGLIP_ID, siglip_kw)
        vdim = self.vision_backbone.featurizer.embed_dim + self.vision_backbone.fused_featurizer.embed_dim
        llm = llm_kw["hidden_size"]
        self.projector = torch.nn.Module()
        self.projector.fc1 = torch.nn.Linear(vdim, 4 * vdim)
        self.projector.fc2 = torch.nn.Linear(4 * vdim, llm)
        self.projector.fc3 = torch.nn.Linear(llm, llm)
        self.language_model = LlamaForCausalLM(LlamaConfig(**llm_kw, attn_implementation="eager"))

    def vision(self, pixel_values):
        img, img_fused = torch.split(pixel_values, [3, 3], dim=1)
        a = self.vision_backbone.featurizer(img)
        b = self.vision_backbone.fused_featurizer(img_fused)
        return torch.cat([a, b], dim=2)

    def project(self, patches):
        gelu = torch.nn.functional.gelu
        return self.projector.fc3(gelu(self.projector.fc2(gelu(self.projector.fc1(patches)))))


def randomize(model: TinyOpenVLA, gen: torch.Generator):
    """Random weights everywhere, scaled so activations stay O(1) (timm/HF inits leave LayerScale at
    1e-5 and tokens near 0, which would hide mistakes); the action tokens' lm_head rows are scaled up
    so that greedy decoding lands on action bins, as a trained OpenVLA does."""
    with torch.no_grad():
        for name, p in model.named_parameters():
            randn = partial(torch.randn, p.shape, generator=gen, device=p.device, dtype=p.dtype)
            if p.dim() == 1 and ("norm" in name or name.endswith("scale_factor")):
                p.copy_(1.0 + 0.2 * randn())
            elif p.dim() == 1:
                p.copy_(0.1 * randn())
            else:
                fan_in = p.shape[1] if p.dim() == 2 else int(np.prod(p.shape[1:]))
                std = 1.0 / np.sqrt(fan_in) if p.dim() in (2, 4) else 0.5
                if name.endswith("embed_tokens.weight"):
                    std = 1.0
                p.copy_(std * randn())
        head = model.language_model.lm_head.weight
        head[32000 - N_ACTION_BINS:32000] *= 3.0


def norm_stats():
    rng = np.random.RandomState(7)
    q01 = np.round(-rng.uniform(0.2, 1.0, 7), 6)
    q99 = np.round(rng.uniform(0.2, 1.0, 7), 6)
    q01[6], q99[6] = 0.0, 1.0
    action = {
        "mean": np.round(rng.uniform(-0.1, 0.1, 7), 6).tolist(), "std": np.round(rng.uniform(0.1, 0.5, 7), 6).tolist(),
        "max": (q99 + 0.1).tolist(), "min": (q01 - 0.1).tolist(), "q01": q01.tolist(), "q99": q99.tolist(),
        "mask": [True] * 6 + [False],
    }
    zeros = [0.0] * 7
    proprio = {"mean": zeros, "std": zeros, "max": zeros, "min": zeros, "q01": zeros, "q99": zeros}
    return {UNNORM_KEY: {"action": action, "proprio": proprio, "num_transitions": 1000, "num_trajectories": 10}}


def save_checkpoint(model: TinyOpenVLA, out_dir: str, stats: dict, n_shards: int = 2, timm_kwargs=(DINO_KW, SIGLIP_KW)):
    state = model.state_dict()
    keys = sorted(state)
    per = -(-len(keys) // n_shards)
    shards = [keys[i:i + per] for i in range(0, len(keys), per)]
    weight_map, total = {}, 0
    for i, shard in enumerate(shards):
        fname = f"model-{i + 1:05d}-of-{len(shards):05d}.safetensors"
        # on the host, one shard at a time (the 7B model's weights live on the GPU)
        tensors = {k: state[k].detach().to("cpu", copy=True).contiguous() for k in shard}
        save_file(tensors, os.path.join(out_dir, fname), metadata={"format": "pt"})
        for k in shard:
            weight_map[k] = fname
            total += state[k].numel() * state[k].element_size()
        del tensors
    with open(os.path.join(out_dir, "model.safetensors.index.json"), "w") as f:
        json.dump({"metadata": {"total_size": total}, "weight_map": weight_map}, f, indent=2)
    save_configs(model, out_dir, stats, timm_kwargs)


def save_configs(model: TinyOpenVLA, out_dir: str, stats: dict, timm_kwargs=(DINO_KW, SIGLIP_KW)):
    """config.json, dataset_statistics.json and preprocessor_config.json of the checkpoint (no weights)."""
    # As PretrainedConfig.to_diff_dict writes a nested config (the released config.json's text_config
    # has only what differs from LlamaConfig's defaults, e.g. no rope_theta, no rms_norm_eps when 1e-6).
    full, default = model.language_model.config.to_dict(), LlamaConfig().to_dict()
    text_config = {k: v for k, v in full.items() if k not in default or default[k] != v}
    for k in ("architectures", "_name_or_path", "transformers_version", "torch_dtype", "_attn_implementation_autoset"):
        text_config.pop(k, None)
    text_config["model_type"] = "llama"
    config = {
        "architectures": ["OpenVLAForActionPrediction"],
        "model_type": "openvla",
        "vision_backbone_id": "dinosiglip-vit-so-224px",
        "llm_backbone_id": "llama2-7b-pure",
        "arch_specifier": "no-align+fused-gelu-mlp",
        "use_fused_vision_backbone": True,
        "image_resize_strategy": "resize-naive",
        "timm_model_ids": [DINO_ID, SIGLIP_ID],
        "timm_override_act_layers": [None, None],
        # Not in OpenVLA's config: the tiny model's overrides of the timm model functions' defaults.
        **({"timm_model_kwargs": list(timm_kwargs)} if timm_kwargs else {}),
        "image_sizes": [224, 224],
        "text_config": text_config,
        "llm_max_length": 2048,
        "pad_token_id": 32000,
        "pad_to_multiple_of": PAD_TO_MULTIPLE_OF,
        "n_action_bins": N_ACTION_BINS,
        "norm_stats": stats,
        "output_projector_states": False,
        "torch_dtype": str(next(model.parameters()).dtype).replace("torch.", ""),
    }
    with open(os.path.join(out_dir, "config.json"), "w") as f:
        json.dump(config, f, indent=2)
    with open(os.path.join(out_dir, "dataset_statistics.json"), "w") as f:
        json.dump(stats, f, indent=2)
    pre = {
        "image_processor_type": "PrismaticImageProcessor", "processor_class": "PrismaticProcessor",
        "image_resize_strategy": "resize-naive", "use_fused_vision_backbone": True,
        "input_sizes": [[3, 224, 224], [3, 224, 224]], "interpolations": ["bicubic", "bicubic"],
        "means": [[0.485, 0.456, 0.406], [0.5, 0.5, 0.5]], "stds": [[0.229, 0.224, 0.225], [0.5, 0.5, 0.5]],
        "tvf_crop_params": [{"output_size": [224, 224]}] * 2, "tvf_do_letterbox": False,
        "tvf_normalize_params": TVF_NORMALIZE,
        "tvf_resize_params": [{"antialias": True, "interpolation": 3, "max_size": None, "size": [224, 224]}] * 2,
    }
    with open(os.path.join(out_dir, "preprocessor_config.json"), "w") as f:
        json.dump(pre, f, indent=2)


def pixel_values_of(image: np.ndarray) -> torch.Tensor:
    """PrismaticImageProcessor on a 224x224 image: resize to 224 is the identity, then per backbone
    to_tensor (/255) and normalize ((x - mean) / std), stacked along channels."""
    x = torch.from_numpy(image).permute(2, 0, 1).contiguous().to(torch.float32).div(255)
    parts = []
    for p in TVF_NORMALIZE:
        mean = torch.tensor(p["mean"], dtype=torch.float32)[:, None, None]
        std = torch.tensor(p["std"], dtype=torch.float32)[:, None, None]
        parts.append(x.clone().sub_(mean).div_(std))
    return torch.vstack(parts)[None]


@torch.no_grad()
def predict(model: TinyOpenVLA, tokenizer, image: np.ndarray, instruction: str, stats: dict, ref_dir: str):
    prompt = prompt_for(instruction)
    input_ids = tokenizer(prompt, return_tensors="pt").input_ids
    if not torch.all(input_ids[:, -1] == 29871):
        input_ids = torch.cat((input_ids, torch.tensor([[29871]], dtype=torch.long)), dim=1)
    param = next(model.parameters())
    pixel_values = pixel_values_of(image)
    input_ids, pixel_values = input_ids.to(param.device), pixel_values.to(param.device, param.dtype)
    patches = model.vision(pixel_values)
    projected = model.project(patches)
    lm = model.language_model
    emb = lm.get_input_embeddings()(input_ids)
    mm = torch.cat([emb[:, :1], projected, emb[:, 1:]], dim=1)
    action_dim = len(stats[UNNORM_KEY]["action"]["q01"])
    out = lm(inputs_embeds=mm, use_cache=True)
    logits, tokens = [], []
    for step in range(action_dim):
        last = out.logits[0, -1].float()
        logits.append(last.cpu().numpy().copy())
        tok = int(torch.argmax(last))
        tokens.append(tok)
        if step + 1 < action_dim:
            out = lm(input_ids=torch.tensor([[tok]], device=param.device), past_key_values=out.past_key_values, use_cache=True)
    vocab_size = LLM["vocab_size"] - PAD_TO_MULTIPLE_OF
    bins = np.linspace(-1, 1, N_ACTION_BINS)
    centers = (bins[:-1] + bins[1:]) / 2.0
    disc = np.clip(vocab_size - np.array(tokens) - 1, 0, centers.shape[0] - 1)
    normalized = centers[disc]
    a = stats[UNNORM_KEY]["action"]
    mask = np.array(a["mask"], dtype=bool)
    hi, lo = np.array(a["q99"]), np.array(a["q01"])
    action = np.where(mask, 0.5 * (normalized + 1) * (hi - lo) + lo, normalized)
    host = lambda t: t.float().cpu().numpy()  # noqa: E731  (bf16 has no numpy dtype)
    np.save(os.path.join(ref_dir, "input_ids.npy"), input_ids.cpu().numpy().astype(np.int64))
    np.save(os.path.join(ref_dir, "pixel_values.npy"), host(pixel_values))
    np.save(os.path.join(ref_dir, "patch_features.npy"), host(patches))
    np.save(os.path.join(ref_dir, "projected.npy"), host(projected))
    np.save(os.path.join(ref_dir, "step_logits.npy"), np.stack(logits).astype(np.float32))
    expected = {
        "instruction": instruction, "prompt": prompt, "unnorm_key": UNNORM_KEY,
        "input_ids": input_ids[0].tolist(), "dtype": str(param.dtype), "device": str(param.device), "tokens": tokens, "bins": disc.tolist(),
        "normalized_action": normalized.tolist(), "action": action.tolist(),
        "versions": {"torch": torch.__version__, "timm": timm.__version__,
                     "transformers": sys.modules["transformers"].__version__},
    }
    with open(os.path.join(ref_dir, "expected.json"), "w") as f:
        json.dump(expected, f, indent=2)
    return expected


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("out_dir")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    torch.manual_seed(args.seed)
    torch.set_num_threads(1)
    out_dir = args.out_dir
    ref_dir = os.path.join(out_dir, "reference")
    os.makedirs(ref_dir, exist_ok=True)
    tokenizer = build_tokenizer(out_dir)
    model = TinyOpenVLA().eval()
    randomize(model, torch.Generator().manual_seed(args.seed))
    stats = norm_stats()
    save_checkpoint(model, out_dir, stats)
    image = np.random.RandomState(args.seed + 1).randint(0, 256, (224, 224, 3)).astype(np.uint8)
    np.save(os.path.join(ref_dir, "image.npy"), image)
    expected = predict(model, tokenizer, image, INSTRUCTION, stats, ref_dir)
    print(json.dumps({k: expected[k] for k in ("tokens", "bins", "action")}))


if __name__ == "__main__":
    main()
