"""Which weight-only quantised matmuls torch 2.11 has on this GPU, at Llama-2-7B's shapes, and what
they cost and how far they are from bf16 (issue 22, small GPUs: the kernels `?quant=int8|int4`
would call through tch).

usage: python3 weight_only_kernels.py [--json OUT.json]

For each weight shape (N x K: q/k/v/o 4096 x 4096, gate/up 11008 x 4096, down 4096 x 11008) and
M = 1 (one decode step) and 32 (a batch): torch.nn.functional.linear in bf16; torch._weight_int8pack_mm
(per-output-channel symmetric int8, scales in bf16); torch._weight_int4pack_mm (tinygemm, group size
128, asymmetric, packed by torch._convert_weight_to_int4pack). Median of 50 timed calls after 10
warm-ups, CUDA synchronised; the error is max |y_q - y_bf16| / max |y_bf16| on random data.
"""

import argparse
import json
import time

import torch


def timed(fn, iters=50, warmup=10):
    for _ in range(warmup):
        fn()
    torch.cuda.synchronize()
    times = []
    for _ in range(iters):
        t = time.perf_counter()
        fn()
        torch.cuda.synchronize()
        times.append(time.perf_counter() - t)
    times.sort()
    return times[len(times) // 2] * 1e3


def int8_weights(w):
    scales = w.float().abs().amax(dim=1).clamp(min=1e-8) / 127
    q = torch.round(w.float() / scales[:, None]).clamp(-128, 127).to(torch.int8)
    return q, scales.to(torch.bfloat16)


def int4_weights(w, group=128, inner_k_tiles=8):
    n, k = w.shape
    g = w.float().reshape(n, k // group, group)
    lo, hi = g.amin(-1), g.amax(-1)
    scales = ((hi - lo).clamp(min=1e-6) / 15)
    zeros = lo + scales * 8  # tinygemm: w = (q - 8) * scale + zero
    q = torch.round((g - lo[..., None]) / scales[..., None]).clamp(0, 15).to(torch.int32).reshape(n, k)
    packed_u8 = (q[:, ::2] << 4 | q[:, 1::2]).to(torch.uint8)
    packed = torch._convert_weight_to_int4pack(packed_u8, inner_k_tiles)
    sz = torch.stack([scales, zeros], dim=-1).transpose(0, 1).contiguous().to(torch.bfloat16)  # [K/g, N, 2]
    return packed, sz


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--json")
    args = ap.parse_args()
    dev = "cuda"
    rows = []
    print(f"torch {torch.__version__} on {torch.cuda.get_device_name()}")
    for n, k in ((4096, 4096), (11008, 4096), (4096, 11008)):
        w = (torch.randn(n, k, device=dev) / k**0.5).to(torch.bfloat16)
        q8, s8 = int8_weights(w)
        try:
            q4, sz4 = int4_weights(w)
            int4_error = None
        except Exception as e:  # noqa: BLE001 - the probe reports what the build lacks
            q4, int4_error = None, f"{type(e).__name__}: {e}"[:300]
        for m in (1, 32):
            x = torch.randn(m, k, device=dev).to(torch.bfloat16)
            ref = torch.nn.functional.linear(x, w)
            row = {"n": n, "k": k, "m": m, "bf16_ms": timed(lambda: torch.nn.functional.linear(x, w))}
            try:
                y8 = torch._weight_int8pack_mm(x, q8, s8)
                row["int8_ms"] = timed(lambda: torch._weight_int8pack_mm(x, q8, s8))
                row["int8_rel_error"] = float((y8.float() - ref.float()).abs().max() / ref.float().abs().max())
            except Exception as e:  # noqa: BLE001
                row["int8_error"] = f"{type(e).__name__}: {e}"[:300]
            if q4 is not None:
                try:
                    y4 = torch._weight_int4pack_mm(x, q4, 128, sz4)
                    row["int4_ms"] = timed(lambda: torch._weight_int4pack_mm(x, q4, 128, sz4))
                    row["int4_rel_error"] = float((y4.float() - ref.float()).abs().max() / ref.float().abs().max())
                except Exception as e:  # noqa: BLE001
                    row["int4_error"] = f"{type(e).__name__}: {e}"[:300]
            else:
                row["int4_error"] = int4_error
            print(json.dumps(row), flush=True)
            rows.append(row)
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"torch": torch.__version__, "device": torch.cuda.get_device_name(), "rows": rows}, f, indent=2)


if __name__ == "__main__":
    main()
