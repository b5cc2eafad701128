# The GPU check of this session: run by the device tool from the repo root, $OUT comes back.
set -u
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
nvidia-smi -L; nproc; python3 -c "import torch, numpy, torch_geometric; print(torch.__version__, numpy.__version__, torch_geometric.__version__, torch.cuda.get_device_name(0))"
lscpu | grep -E "Model name|^CPU\(s\)"
echo "== paper preset timing"
timeout 300 python3 perf/paper_speed.py --set .carry/paper_set.npz --device cuda --steps 12 --out $OUT/paper_speed.json 2>&1 | grep -v Warning | tee $OUT/paper_speed.log
echo "== tiny preset on cuda (benchmark reproduce)"
t0=$(date +%s)
timeout 120 python3 -m benchmark.cli reproduce --preset tiny --data .carry/tiny-v3 --out /tmp/tiny --quiet > $OUT/tiny.log 2>&1; echo "rc $? in $(( $(date +%s) - t0 )) s"
tail -5 $OUT/tiny.log; cp /tmp/tiny/table.md /tmp/tiny/table.json $OUT/ 2>/dev/null
echo "== same seed twice on cuda: same weights?"
for k in a b; do timeout 45 python3 -m benchmark.cli train --data .carry/tiny-v3 --out /tmp/det-$k --embedding graph --regime basic --dim 16 --embed-layers 1 --agg-layers 1 --n-heads 2 --decoder-hidden 32 --codebook-size 16 --epochs 3 --batch-size 2 --quiet 2>&1 | tail -1; done
python3 -c "
import torch
a, b = (torch.load(f'/tmp/det-{k}/model.pt', weights_only=True) for k in 'ab')
d = max((a[n].double() - b[n].double()).abs().max().item() for n in a if a[n].is_floating_point())
print('identical' if all(torch.equal(a[n], b[n]) for n in a) else f'differ: max |diff| {d:.3g}')"
