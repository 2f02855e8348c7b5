"""The host-side split of every input-bound hand-off in a job's steady runs (with submissions).

Usage: python handoff_split.py JOB/runs OUT.csv  (prints medians by the number of inputs from other GPUs
and by configuration)."""
import sys, glob, os, pandas as pd, numpy as np
sys.path.insert(0, str(__import__('pathlib').Path(__file__).resolve().parents[3]))
from mgpusim.results.waits import _ready_rows, parse_waits_for
root = sys.argv[1]
out = []
for d in sorted(glob.glob(f'{root}/*/steady')):
    name = d.split('/')[-2]
    t = pd.read_csv(f'{d}/trace.csv'); s = pd.read_csv(f'{d}/submissions.csv')
    dev_of = {(r.task): r.device for r in t.drop_duplicates('task').itertuples()}
    rows = _ready_rows(t, 1)
    rows = rows[rows.binding != 'queue'].astype({'task': 'string'})
    rows = rows.merge(s[['frame','task','inputs_seen_ns','submit_ns','submitted_ns']].astype({'task':'string'}), on=['frame','task'])
    for r in rows.itertuples():
        ins = parse_waits_for(r.waits_for)
        other = [n for o, n in ins if dev_of.get(n) != r.device]
        out.append(dict(config=name, edge=r.edge, n_in=len(ins), n_other=len(other), engine=r.engine,
                        seen=(r.inputs_seen_ns - r.ready_ns)/1e3, call=(r.submit_ns - r.inputs_seen_ns)/1e3,
                        start=(r.start_ns - r.submit_ns)/1e3, wait=(r.start_ns-r.ready_ns)/1e3))
df = pd.DataFrame(out)
df.to_csv(sys.argv[2], index=False)
g = df.groupby(['n_other']).agg(n=('seen','size'), seen=('seen','median'), call=('call','median'), start=('start','median'), wait=('wait','median'))
print(g.round(0))
print(df.groupby(['config']).agg(n=('seen','size'), n_other=('n_other','max'), seen=('seen','median'), call=('call','median'), start=('start','median'), wait=('wait','median')).round(0).to_string())
