# One OpenVLA-7B (Llama-2) decoder layer at the B=64 prefill's shapes, timed op group by op group
# with the operations policies/src/models/openvla/llama.rs issues (fusion "all": rows > 8 so the
# projections are separate GEMMs), to find where the forward's time goes.
import torch, time, sys
torch.manual_seed(0)
dev, dt = "cuda", torch.bfloat16
B, T, H, NH, HD, I = 64, int(sys.argv[1]) if len(sys.argv) > 1 else 280, 4096, 32, 128, 11008
x = torch.randn(B, T, H, device=dev, dtype=dt)
wq, wk, wv, wo = [torch.randn(H, H, device=dev, dtype=dt) * 0.02 for _ in range(4)]
wg, wu = [torch.randn(I, H, device=dev, dtype=dt) * 0.02 for _ in range(2)]
wd = torch.randn(H, I, device=dev, dtype=dt) * 0.02
n1 = torch.ones(H, device=dev, dtype=dt); n2 = torch.ones(H, device=dev, dtype=dt)
inv = 1.0 / (10000 ** (torch.arange(0, HD, 2, device=dev).float() / HD))
pad = torch.randint(0, 8, (B,), device=dev)
pos = (torch.arange(T, device=dev)[None] - pad[:, None]).clamp_min(0).float()
fr = pos[..., None] * inv.view(1, 1, -1); emb = torch.cat([fr, fr], -1)[:, None]
cos, sin = emb.cos().to(dt), emb.sin().to(dt)
keys = torch.arange(T, device=dev); q_ = torch.arange(T, device=dev)
masked = (keys[None] > q_[:, None])[None] | (keys.view(1, 1, -1) < pad.view(-1, 1, 1))
mask = torch.zeros(masked.shape, device=dev, dtype=dt).masked_fill(masked, -3.3895313892515355e38)[:, None]

def rope(t):
    t1 = t[..., : HD // 2]
    rot = torch.cat([-t[..., HD // 2 :], t1], -1)
    return (t * cos).addcmul(rot, sin)

def timeit(name, f, n=20):
    for _ in range(3): f()
    s, e = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
    torch.cuda.synchronize(); s.record()
    for _ in range(n): out = f()
    e.record(); torch.cuda.synchronize()
    ms = s.elapsed_time(e) / n
    print(f"{name:48s} {ms:7.3f} ms  (x32 layers: {32*ms:6.1f} ms)")
    return out

h = timeit("rms_norm", lambda: n1 * torch.nn.functional.rms_norm(x, [H], eps=1e-6))
def heads(w, n=NH): return torch.nn.functional.linear(h, w).view(B, T, n, HD).transpose(1, 2)
q = timeit("q,k,v GEMMs", lambda: (heads(wq), heads(wk), heads(wv)))
qq, kk, vv = q
timeit("q,k,v GEMMs + rope(q,k)", lambda: (rope(heads(wq)), rope(heads(wk)), heads(wv)))
timeit("rope(q) + rope(k) alone", lambda: (rope(qq), rope(kk)))
rq, rk = rope(qq), rope(kk)
print("rope out contiguous:", rq.is_contiguous(), rq.stride())
from torch.nn.attention import sdpa_kernel, SDPBackend
o = timeit("sdpa, additive mask (default backend)", lambda: torch.nn.functional.scaled_dot_product_attention(rq, rk, vv, attn_mask=mask))
for be in (SDPBackend.EFFICIENT_ATTENTION, SDPBackend.CUDNN_ATTENTION, SDPBackend.MATH, SDPBackend.FLASH_ATTENTION):
    try:
        with sdpa_kernel([be]):
            timeit(f"sdpa mask, {be.name}", lambda: torch.nn.functional.scaled_dot_product_attention(rq, rk, vv, attn_mask=mask))
    except Exception as ex:
        print(f"sdpa mask, {be.name}: not available ({str(ex).splitlines()[0][:90]})")
Tp = (T + 15) // 16 * 16
maskp = torch.zeros(B, 1, T, Tp, device=dev, dtype=dt); maskp[..., :T] = mask; maskp = maskp[..., :T]
timeit("sdpa, mask with 16-aligned row stride", lambda: torch.nn.functional.scaled_dot_product_attention(rq, rk, vv, attn_mask=maskp))
timeit("sdpa, is_causal (no padding), flash", lambda: torch.nn.functional.scaled_dot_product_attention(rq, rk, vv, is_causal=True))
timeit("o transpose+reshape + o GEMM + residual", lambda: x + torch.nn.functional.linear(o.transpose(1, 2).reshape(B, T, H), wo))
h2 = n2 * torch.nn.functional.rms_norm(x, [H], eps=1e-6)
timeit("gate, up GEMMs", lambda: (torch.nn.functional.linear(h2, wg), torch.nn.functional.linear(h2, wu)))
g, u = torch.nn.functional.linear(h2, wg), torch.nn.functional.linear(h2, wu)
timeit("silu(g) * u", lambda: torch.nn.functional.silu(g) * u)
gu = torch.nn.functional.silu(g) * u
timeit("down GEMM + residual", lambda: x + torch.nn.functional.linear(gu, wd))
def layer():
    h = n1 * torch.nn.functional.rms_norm(x, [H], eps=1e-6)
    hs = lambda w: torch.nn.functional.linear(h, w).view(B, T, NH, HD).transpose(1, 2)
    q, k, v = rope(hs(wq)), rope(hs(wk)), hs(wv)
    o = torch.nn.functional.scaled_dot_product_attention(q, k, v, attn_mask=mask)
    y = x + torch.nn.functional.linear(o.transpose(1, 2).reshape(B, T, H), wo)
    h = n2 * torch.nn.functional.rms_norm(y, [H], eps=1e-6)
    return y + torch.nn.functional.linear(torch.nn.functional.silu(torch.nn.functional.linear(h, wg)) * torch.nn.functional.linear(h, wu), wd)
timeit("WHOLE LAYER (as llama.rs)", layer)
# decode: one step at B=64 against a cache of T positions
kc, vc = torch.randn(B, NH, T, HD, device=dev, dtype=dt), torch.randn(B, NH, T, HD, device=dev, dtype=dt)
k1 = torch.randn(B, NH, 1, HD, device=dev, dtype=dt)
timeit("decode: KV cat (k and v)", lambda: (torch.cat([kc, k1], 2), torch.cat([vc, k1], 2)))
kf = torch.cat([kc, k1], 2); m1 = torch.zeros(B, 1, 1, T + 1, device=dev, dtype=dt)
q1 = torch.randn(B, NH, 1, HD, device=dev, dtype=dt)
timeit("decode: sdpa 1 query, mask", lambda: torch.nn.functional.scaled_dot_product_attention(q1, kf, kf, attn_mask=m1))
x1 = torch.randn(B, 1, H, device=dev, dtype=dt)
timeit("decode: 7 GEMMs of 64 rows", lambda: [torch.nn.functional.linear(x1, w) for w in (wq, wk, wv, wo)] + [torch.nn.functional.linear(x1, w) for w in (wg, wu)] + [torch.nn.functional.linear(torch.randn(B,1,I,device=dev,dtype=dt), wd)])
