"""Contact-map build cost by where the faults sit (default converged meshes and grid), built without the
disk cache; prints the table of docs/GEAR-CONTACT.md ("Map cost by where the faults sit").

    python benchmarks/bench_map_build.py          # about 4 minutes on 2 cores
"""
import io
import time

import numpy as np

from gearcontact_fmu import contact_map as cm
cases = [("healthy", "healthy", None),
         ("pinion void (tooth 0)", "faults", [{"kind": "void", "member": "pinion", "tooth": 0}]),
         ("wheel void (tooth 38)", "faults", [{"kind": "void", "member": "wheel", "tooth": 38}]),
         ("wheel pit (tooth 38, R 1.5 mm)", "faults", [{"kind": "pit", "member": "wheel", "tooth": 38}]),
         ("pinion + wheel void", "faults", [{"kind": "void", "member": "pinion", "tooth": 0},
                                            {"kind": "void", "member": "wheel", "tooth": 38}])]
print("| faults | pinion revolutions | blocks computed | rows | build [s] | file [MB] |")
print("|---|---|---|---|---|---|")
for label, health, faults in cases:
    t0 = time.perf_counter()
    m = cm.get_map(health=health, use_cache=False, fault_kwargs={"faults": faults} if faults else None)
    t = time.perf_counter() - t0
    buf = io.BytesIO(); np.savez_compressed(buf, values=m.values, onset=m.onset)
    print(f"| {label} | {m.info['pinion_revolutions']} | {m.info['blocks_computed']} of {len(m.theta)//48} | "
          f"{len(m.theta)} | {t:.1f} | {len(buf.getvalue())/1e6:.1f} |", flush=True)
