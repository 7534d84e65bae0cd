import torch, sys
torch.manual_seed(0)
dev, dt = "cuda", torch.bfloat16
B, T, H, NH, HD = 64, 280, 4096, 32, 128
def timeit(name, f, n=20):
    for _ in range(3): f()
    s, e = torch.cuda.Event(enable_timing=True), torch.cuda.Event(enable_timing=True)
    torch.cuda.synchronize(); s.record()
    for _ in range(n): out = f()
    e.record(); torch.cuda.synchronize()
    ms = s.elapsed_time(e) / n
    print(f"{name:56s} {ms:7.3f} ms  (x32: {32*ms:6.1f} ms)", flush=True)
    return out
h = torch.randn(B * T, H, device=dev, dtype=dt)
wq = torch.randn(H, H, device=dev, dtype=dt) * 0.02
inv = 1.0 / (10000 ** (torch.arange(0, HD, 2, device=dev).float() / HD))
pos = torch.arange(T, device=dev)[None].expand(B, T).float()
fr = pos[..., None] * inv; emb = torch.cat([fr, fr], -1)
cos4, sin4 = emb.cos().to(dt)[:, None], emb.sin().to(dt)[:, None]          # [B,1,T,HD] (llama.rs)
cosc, sinc = emb.cos().to(dt)[:, :, None], emb.sin().to(dt)[:, :, None]    # [B,T,1,HD]
q = torch.nn.functional.linear(h, wq)
def cur():
    x = q.view(B, T, NH, HD).transpose(1, 2)
    rot = torch.cat([-x[..., HD // 2:], x[..., :HD // 2]], -1)
    return (x * cos4).addcmul(rot, sin4)
def contig():
    x = q.view(B, T, NH, HD)
    rot = torch.cat([-x[..., HD // 2:], x[..., :HD // 2]], -1)
    return (x * cosc).addcmul(rot, sinc).transpose(1, 2)
sin_signed = torch.cat([-emb[..., :HD // 2].sin(), emb[..., HD // 2:].sin()], -1).to(dt)[:, :, None]
def halves():
    # out = x*cos + swap_halves(x)*sin_signed ; swap via roll (one copy kernel)
    x = q.view(B, T, NH, HD)
    return torch.addcmul(x * cosc, x.roll(HD // 2, -1), sin_signed).transpose(1, 2)
def halves_out():
    x = q.view(B, T, NH, HD)
    out = torch.empty_like(x)
    torch.mul(x, cosc, out=out)
    return out.addcmul_(x.roll(HD // 2, -1), sin_signed).transpose(1, 2)
ref = cur()
for name, f in (("rope as llama.rs (transposed view)", cur), ("rope on [B,T,NH,HD] contiguous", contig), ("rope roll + signed sin", halves), ("rope roll + signed sin, in place", halves_out)):
    r = timeit(name, f)
    print("   max diff vs llama.rs:", (r.float() - ref.float()).abs().max().item())
# SDPA on contiguous-layout q (transposed view) vs contiguous [B,NH,T,HD]
k = contig(); v = q.view(B, T, NH, HD).transpose(1, 2)
pad = torch.randint(0, 8, (B,), device=dev); keys = torch.arange(T, device=dev)
masked = (keys[None] > keys[:, None])[None] | (keys.view(1, 1, -1) < pad.view(-1, 1, 1))
mask = torch.zeros(masked.shape, device=dev, dtype=dt).masked_fill(masked, -3.3895313892515355e38)[:, None]
timeit("sdpa q,k,v transposed views", lambda: torch.nn.functional.scaled_dot_product_attention(k, k, v, attn_mask=mask))
kc, vcc = k.contiguous(), v.contiguous()
timeit("sdpa q,k,v contiguous", lambda: torch.nn.functional.scaled_dot_product_attention(kc, kc, vcc, attn_mask=mask))
boolmask = ~masked[:, None]
timeit("sdpa bool mask", lambda: torch.nn.functional.scaled_dot_product_attention(k, k, v, attn_mask=boolmask))
# static cache decode: write into a buffer, attend over a narrow view
Tm = T + 8
buf_k = torch.zeros(B, NH, Tm, HD, device=dev, dtype=dt); buf_v = torch.zeros_like(buf_k)
k1 = torch.randn(B, NH, 1, HD, device=dev, dtype=dt); q1 = torch.randn(B, NH, 1, HD, device=dev, dtype=dt)
m1 = torch.zeros(B, 1, 1, T + 1, device=dev, dtype=dt)
def static_step():
    buf_k.narrow(2, T, 1).copy_(k1); buf_v.narrow(2, T, 1).copy_(k1)
    return torch.nn.functional.scaled_dot_product_attention(q1, buf_k.narrow(2, 0, T + 1), buf_v.narrow(2, 0, T + 1), attn_mask=m1)
timeit("decode: static cache write + sdpa (narrow view)", static_step)
kcache, vcache = buf_k.narrow(2, 0, T).contiguous(), buf_v.narrow(2, 0, T).contiguous()
def cat_step():
    kk, vv = torch.cat([kcache, k1], 2), torch.cat([vcache, k1], 2)
    return torch.nn.functional.scaled_dot_product_attention(q1, kk, vv, attn_mask=m1)
timeit("decode: cat + sdpa (llama.rs)", cat_step)
# decode GEMMs at 64 rows: separate vs stacked
x1 = torch.randn(B, H, device=dev, dtype=dt)
W = [torch.randn(H, H, device=dev, dtype=dt) for _ in range(3)]; Wqkv = torch.cat(W, 0)
timeit("decode: q,k,v GEMMs separate (64 rows)", lambda: [torch.nn.functional.linear(x1, w) for w in W])
timeit("decode: qkv stacked GEMM (64 rows)", lambda: torch.nn.functional.linear(x1, Wqkv))
G = [torch.randn(11008, H, device=dev, dtype=dt) for _ in range(2)]; Ggu = torch.cat(G, 0)
timeit("decode: gate, up separate (64 rows)", lambda: [torch.nn.functional.linear(x1, w) for w in G])
timeit("decode: gate_up stacked (64 rows)", lambda: torch.nn.functional.linear(x1, Ggu))
# vision: a SigLIP-so400m-like block and a DINOv2-L-like block over 64 images x 256 tokens
for name, C, M, heads, n, L in (("siglip-like", 1152, 4304, 16, 256, 27), ("dinov2-like", 1024, 4096, 16, 261, 24)):
    xv = torch.randn(B, n, C, device=dev, dtype=dt)
    ws = {k: (torch.randn(o, i, device=dev, dtype=dt) * 0.02, torch.zeros(o, device=dev, dtype=dt)) for k, o, i in (("qkv", 3 * C, C), ("proj", C, C), ("fc1", M, C), ("fc2", C, M))}
    lnw = (torch.ones(C, device=dev, dtype=dt), torch.zeros(C, device=dev, dtype=dt))
    def lin(x, k, mode):
        w, b = ws[k]
        return torch.nn.functional.linear(x, w, b) if mode else x.matmul(w.t()) + b
    def block(mode):
        y = torch.nn.functional.layer_norm(xv, [C], *lnw, 1e-6)
        qkv = lin(y, "qkv", mode).reshape(B, n, 3, heads, C // heads).permute(2, 0, 3, 1, 4)
        o = torch.nn.functional.scaled_dot_product_attention(qkv[0], qkv[1], qkv[2])
        x2 = xv + lin(o.transpose(1, 2).reshape(B, n, C), "proj", mode)
        y = torch.nn.functional.gelu(lin(torch.nn.functional.layer_norm(x2, [C], *lnw, 1e-6), "fc1", mode))
        return x2 + lin(y, "fc2", mode)
    flop = 2 * B * n * (4 * C * C + 2 * C * M) + 4 * B * n * n * C
    for mode in (True,):
        s = torch.cuda.Event(enable_timing=True); e = torch.cuda.Event(enable_timing=True)
        for _ in range(3): block(mode)
        torch.cuda.synchronize(); s.record()
        for _ in range(10): block(mode)
        e.record(); torch.cuda.synchronize(); ms = s.elapsed_time(e) / 10
        print(f"vision {name} block: {ms:.3f} ms, x{L} = {L*ms:.1f} ms, {flop/ms/1e9:.0f} TFLOP/s")
