"""A real Franka Panda's own log, calibrated, and what that does to the suite's predictions.

    python -m baselines.real_panda out=results/real_panda work=/tmp/real_panda episodes=20 seed=1 workers=2

1. Imports Gaz et al.'s excitation log (`../shared/data/real/panda_gaz`, irregular clock: resampled to
   1 kHz by linear interpolation) and calibrates robosuite's Panda, as held_out_robots builds it, by
   inverse dynamics (`bench/calibrate/models/panda_gaz.yaml`): OUT/calibration/.
2. Compares the calibrated model with the one the log's authors identified (Gaz et al., RA-L 2019), on
   the never-repeated stretch the calibration holds out: their predicted torque on the same samples
   (results/references/gaz_panda.json, made by benchmarks/gaz_reference.py from their own code) scored
   by the same code as ours; and their friction law, tau_f = A / (1 + exp(-a (dq + s))) - A / (1 + exp(-a s))
   per joint, against ours on the held-out velocities.
3. Runs a population of policies (scripted expert, noisy, timid and weak-grip experts, the committed
   behaviour-cloning checkpoint and a smaller one trained here on 8 demonstrations per seen arm, random) on the nominal and on the calibrated Panda, the same seeds on
   both, and reports per-policy success with paired intervals and the change in rank order.
4. Runs the scripted expert under `perturb.AXIS=from(calibration)` on damping, dry friction and the
   links' inertia: the measured robot within what the calibration knows about it.

Writes OUT/README.md (the tables), OUT/population.json and OUT/friction.json; the runs go to WORK.
The log has no task success: this measures how calibration moves predictions, not whether it
improves them.
"""

from baselines.real_panda.args import Args
from baselines.real_panda.pipeline import main

__all__ = ["Args", "main"]
