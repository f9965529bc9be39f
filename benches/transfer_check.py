"""Regression check of the default rule on both generators, before and after a change to it:
false alarms on clean curves and recall per fault kind and magnitude, on the independent
generator (tests/independent_generator; CST, CSDT, HDT; white and AR(1) 0.85 noise; 2 kHz,
0.1 deg encoder; 400 clean curves seed 93, 200 faulty per cell seed 91) and on the built-in
simulator (2,000 faulty seed 92, 2,000 clean seed 94). Recall counts undecided curves as
missed. Run: .venv/bin/python benches/transfer_check.py
"""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
import independent_generator as ig  # noqa: E402
import numpy as np  # noqa: E402
import tightscan  # noqa: E402
out=[]
for strat in ("CST","CSDT","HDT"):
  for colour,phi in (("white",0.0),("ar1",0.85)):
    noise=ig.NoiseConfig(colour=colour, phi=phi) if colour!="white" else ig.NoiseConfig()
    c,_ = ig.generate(ig.GeneratorConfig(n=400, seed=93, strategy=strat, encoder_step_deg=0.1, noise=noise))
    r = tightscan.detect_batch(c); d=[v for v in r["change_detected"].to_pylist() if v is not None]
    line=f"{strat} {colour} clean FAR {np.mean(d):.4f} decided {len(d)}"
    for kind in ("abrupt","intermittent","incipient"):
      for mag in ((0.03,0.15),(0.15,0.45)):
        c,truth = ig.generate(ig.GeneratorConfig(n=200, seed=91, strategy=strat, encoder_step_deg=0.1, noise=noise,
                   fault=ig.FaultConfig(kind=kind, magnitude=mag, fraction_faulty=1.0)))
        r = tightscan.detect_batch(c)
        d=[bool(v) for v in r["change_detected"].to_pylist()]
        line+=f" | {kind[:4]}{mag[0]} {np.mean(d):.3f}"
    print(line, flush=True)
c,_=tightscan.simulate(2000, seed=92, fault_fraction=1.0)
r=tightscan.detect_batch(c); d=[bool(v) for v in r["change_detected"].to_pylist()]
print("built-in all faults recall %.4f"%np.mean(d))
c,_=tightscan.simulate(2000, seed=94, fault_fraction=0.0)
r=tightscan.detect_batch(c); d=[v for v in r["change_detected"].to_pylist() if v is not None]
print("built-in clean FAR %.4f decided %d"%(np.mean(d), len(d)))
