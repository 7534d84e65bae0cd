# cuBLAS bf16 `linear` at the shapes of OpenVLA-7B's B = 64 prefill (M = 64 x 280 rows) and half
# of it: the compute the forward's GEMMs can reach on this GPU.
import torch, time
torch.backends.cuda.matmul.allow_bf16_reduced_precision_reduction = True
for M in (17920, 8960):
  for (K, N) in ((4096, 4096), (4096, 11008), (11008, 4096), (4096, 12288), (4096, 22016)):
    a = torch.randn(M, K, device="cuda", dtype=torch.bfloat16); w = torch.randn(N, K, device="cuda", dtype=torch.bfloat16)
    for _ in range(3): torch.nn.functional.linear(a, w)
    torch.cuda.synchronize(); t = time.perf_counter(); n = 20
    for _ in range(n): torch.nn.functional.linear(a, w)
    torch.cuda.synchronize(); dt = (time.perf_counter() - t) / n
    print(f"M={M} K={K} N={N}: {dt*1e3:.2f} ms, {2*M*K*N/dt/1e12:.0f} TFLOP/s")
