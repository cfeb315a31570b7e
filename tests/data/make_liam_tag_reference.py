"""Cut tests/data/liam_tag_reference.npz from LIAM's reference_io.npz (see tests/data/README.md)."""

import sys
from collections import defaultdict

import numpy as np

d = np.load(sys.argv[1])
g = defaultdict(list)
for r, key in enumerate(zip(d["source"], d["episode"], d["t"], strict=True)):
    g[tuple(int(x) for x in key)].append(r)
groups = sorted((k, v) for k, v in g.items() if len(v) > 1)
rows = [r for k, v in groups if len(v) == 3 for r in v]  # the one state seen by all three
for src in (0, 1):  # four states seen by two predators, from each source
    rows += [r for v in [v for k, v in groups if len(v) == 2 and k[0] == src][:4] for r in v]
rest = [r for r in range(len(d["obs"])) if r not in rows]
rows += [rest[i] for i in np.linspace(0, len(rest) - 1, 64 - len(rows)).astype(int)]
rows = sorted(rows)
keys = ["obs", "obs_f32", "source", "episode", "t", "agent_index", "team"]
keys += [f"ia2c_{i}_{k}" for i in range(3) for k in ("logits", "probs")]
keys += [f"maddpg_{i}_{k}" for i in range(3) for k in ("logits", "action")]
keys += [k for k in d.files if k.startswith("heur_")]
out = {k: d[k][rows] for k in keys}
np.savez_compressed(sys.argv[2], row=np.asarray(rows, np.int32), **out)
print(len(rows), np.bincount(out["source"]))
