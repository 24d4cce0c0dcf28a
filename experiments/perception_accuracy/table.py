"""Print results.jsonl as a table: python table.py [name-prefix ...]"""
import json
import sys
from pathlib import Path

rows = [json.loads(l) for l in Path(__file__).with_name("results.jsonl").read_text().splitlines() if l.strip()]
pre = sys.argv[1:]
print(f"{'name':28s} {'test':>6s} {'best':>6s} {'train':>6s} {'seen':>6s} {'blind':>6s} {'s/ep':>5s}  set")
for r in rows:
    if pre and not any(r["name"].startswith(p) for p in pre):
        continue
    print(f"{r['name']:28s} {r['test_rmse']:6.4f} {r['best_test']:6.4f} {r['train_rmse']:6.4f} {r['seen_rmse']:6.4f} "
          f"{r['blind_rmse']:6.4f} {r['sec_per_epoch']:5.1f}  {r['model']} ep{r['epochs']} n{r['max_samples']} "
          f"{' '.join(r['set'])}")
