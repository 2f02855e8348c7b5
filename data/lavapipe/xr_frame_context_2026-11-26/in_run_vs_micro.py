"""Each 1-GPU mesh render of a committed steady main job against two fits: the microbenchmarks'
alone (`profile_microbenchmarks.toml`) and the profile refitted on the runs (`profile.toml`).
Median of the steady window per task, in us; work terms as the schedule gives them.

    .venv/bin/python data/lavapipe/xr_frame_context_2026-11-26/in_run_vs_micro.py JOBDIR

A record of one analysis, not part of the package."""
import sys, tomllib, pandas as pd, numpy as np
sys.path.insert(0, '.')
from mgpusim.schedules.experiment import load_experiment
from mgpusim.schedules.program import build_program
J = sys.argv[1]
study = tomllib.load(open('experiments/lavapipe/study.toml', 'rb'))
cfgs = {c['name']: c for k in ('calibration', 'held_out') for c in study[k]['config']}
micro = tomllib.load(open(f'{J}/profile_microbenchmarks.toml', 'rb'))['gpus'][0]['costs']['mesh']
runs = tomllib.load(open(f'{J}/profile.toml', 'rb'))['gpus'][0]['costs']['mesh']
def cost(c, w):
    return c['fixed_ns'] + sum(c.get('ns_per_' + t, 0) * v for t, v in w.items())
rows = []
for name in ['sl_1gpu_128x96_t5k', 'sl_1gpu_256x192_t5k', 'sl_1gpu_256x192_t10k', 'sl_1gpu_256x192_t20k', 'sl_1gpu_320x240_t40k', 'xr_sim_2views', 'xr_sim_4views']:
    c = cfgs[name]
    from mgpusim.model.overrides import parse_overrides; overrides = parse_overrides(c['set'])
    exp = load_experiment('experiments/lavapipe/' + c['experiment'], overrides=overrides)
    prog = build_program(exp)
    tr = pd.read_csv(f'{J}/runs/{name}/steady/trace.csv')
    for t in prog.templates[0]:
        if getattr(t, 'kind', None) != 'mesh': continue
        d = tr[tr.task == t.name]; m = ((d.end_ns - d.start_ns)).median()
        rows.append(dict(cfg=name, task=t.name, meas=m / 1e3, micro=cost(micro, t.work) / 1e3, runs=cost(runs, t.work) / 1e3, **{k: round(v) for k, v in t.work.items()}))
r = pd.DataFrame(rows)
r['micro%'] = (r.micro / r.meas - 1) * 100; r['runs%'] = (r.runs / r.meas - 1) * 100
pd.set_option('display.width', 250)
print(r.round(1).to_string())
