"""The public API in one script: a model, the engine, a Newmark run, a harmonic balance sweep and
the steady states at one speed (run it: ``python doc/examples/api_example.py [--quick]``)."""
import sys

import dmf_sim as dmf

quick = '--quick' in sys.argv
model = dmf.read_model('truck_dmf', alpha=3.0)                 # Table 1 with the DMF, alpha = 3
engine = dmf.read_engine('engine_d13', load_set='A')           # default engine, Load A
excitation = dmf.DrivelineExcitation(model, engine)           # the engine's torques on it

print('DMF modes [Hz]:', [round(float(f), 1) for f in dmf.modes(model).frequencies_hz[1:4]])

run = dmf.simulate(excitation, speed_rpm=1000.0, load=1.0)     # Newmark to steady state
print('Newmark at 1000 rpm:', run.message)

speeds = (950.0, 1050.0) if quick else (600.0, 2000.0)
res = dmf.sweep(excitation, load=1.0, speed_range=speeds)      # HBM + continuation + Floquet
stable = [r for r in res.rows() if r['stable']]
worst = max(stable, key=lambda r: r['order_1_5'])
print(f"sweep {speeds[0]:g}-{speeds[1]:g} rpm: {len(res.rows())} points, worst stable 1.5th "
      f"order {worst['order_1_5'] * 1e3:.2f} mrad at {worst['speed_rpm']:g} rpm")

try:
    dmf.read_model('truck_dmf', alpha=-1.0)                    # bad input: one line, no traceback
except dmf.ConfigError as exc:
    print('refused:', exc)
