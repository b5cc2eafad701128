set -u
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
echo "== aggregator memory probe"
timeout 70 python3 - <<'PY' 2>&1 | grep -v Warn
import time, torch
from benchmark.training.models.aggregator import Aggregator
torch.manual_seed(0)
dev = torch.device("cuda")
agg = Aggregator(256, 6, 8).to(dev)
B, L = 32, 4000
emb = torch.randn(B, L, 256, device=dev)
mask = torch.arange(L, device=dev)[None, :] < torch.linspace(3000, L, B, device=dev)[:, None]
def run(train, fast):
    torch.backends.mha.set_fastpath_enabled(fast)
    agg.train(train)
    torch.cuda.synchronize(); torch.cuda.reset_peak_memory_stats()
    t0 = time.perf_counter()
    with torch.set_grad_enabled(train):
        out = agg(emb, mask)
        if train:
            out.sum().backward()
    torch.cuda.synchronize()
    return out.detach(), time.perf_counter() - t0, torch.cuda.max_memory_allocated() / 2**30
for train, fast in [(False, True), (False, False), (True, True)]:
    run(train, fast)
    out, s, gib = run(train, fast)
    print(f"train={train} fastpath={fast}: {s*1e3:.0f} ms, peak {gib:.1f} GiB")
    if not train:
        ref = out if fast else ref
        print("  max |diff| vs fastpath:", (out - ref).abs().max().item())
PY
echo "== the remaining rows"
cp .carry/paper_speed.json $OUT/paper_speed.json
timeout 200 python3 perf/paper_speed.py --set .carry/paper_set.npz --device cuda --steps 12 --out $OUT/paper_speed.json 2>&1 | grep -v Warn | tee $OUT/paper_speed2.log
