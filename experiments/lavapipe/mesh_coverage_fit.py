"""Fits of the mesh cost on the probe's placements (mesh_coverage_probe.py): triangles + pixels
against the placed terms (visible triangles, triangle edges, fragments), on all placements and
fitted on sizes up to 256x192 then checked on the larger ones; rms and worst relative error.
The fastest of several probe files is used where given more than one."""
import json, sys
from pathlib import Path
import numpy as np
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
from mgpusim.model.geometry import coverage, MeshView
from scipy.optimize import nnls
best = {}
for f in sys.argv[1:]:
    for line in open(f):
        r = json.loads(line)
        key = json.dumps({k: v for k, v in r.items() if k != "ns"}, sort_keys=True)
        best[key] = min(best.get(key, float("inf")), r["ns"])
rows = [{**json.loads(k), "ns": v} for k, v in best.items()]
def feats(r):
    rect = tuple(r["rect"]) if r["rect"] else None
    c = coverage(MeshView(r["T"], (r["w"], r["h"]), rect, r["first"], r["count"], r["eye"]))
    px = (rect[2] * rect[3]) if rect else r["w"] * r["h"]
    return dict(one=1.0, tri=r["count"], px=px, frag=c.fragments, edge=c.edge, reach=c.triangles)
F = [feats(r) for r in rows]; y = np.array([r["ns"] for r in rows], float)
small = np.array([r["w"] <= 256 for r in rows])
models = {"A tri+px": ["one","tri","px"], "B +frag": ["one","tri","px","frag"],
          "C +edge": ["one","tri","px","frag","edge"], "D reach": ["one","reach","px","frag","edge"],
          "E tri+reach+frag+edge": ["one","tri","reach","px","frag","edge"], "F tri+px+edge": ["one","tri","px","edge"],
          "G tri+reach+px+frag": ["one","tri","reach","px","frag"]}
for name, cols in models.items():
    X = np.array([[f[c] for c in cols] for f in F])
    for label, fitmask in (("all", np.ones(len(y), bool)), ("small->big", small)):
        Xw = X[fitmask] / y[fitmask, None]
        coef, _ = nnls(Xw, np.ones(fitmask.sum()))
        err = X @ coef / y - 1
        test = ~fitmask if label != "all" else fitmask
        print(f"{name:24s} {label:10s} rms {np.sqrt(np.mean(err[test]**2))*100:5.1f}% worst {np.max(np.abs(err[test]))*100:5.1f}%  " + " ".join(f"{c}={v:.4g}" for c, v in zip(cols, coef)))
cols = models["E tri+reach+frag+edge"]  # the placed model: its largest residuals
X = np.array([[f[c] for c in cols] for f in F])
coef,_ = nnls(X / y[:, None], np.ones(len(y)))
err = X @ coef / y - 1
for r, e, yy in sorted(zip(rows, err, y), key=lambda t: -abs(t[1]))[:25]:
    kind = "share" if r["count"] != r["T"] else ("view" if r["rect"] and r["eye"] is not None else ("strip" if r["rect"] else ("eye" if r["eye"] is not None else "whole")))
    print(f'{r["w"]}x{r["h"]} T={r["T"]} {kind} first={r["first"]} eye={r["eye"]} rect={r["rect"]} ms={yy/1e6:.2f} err={e*100:+.1f}%')
