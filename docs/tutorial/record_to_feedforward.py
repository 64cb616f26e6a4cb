# %% [markdown]
# # From a measured record to a feedforward on the machine
#
# A control engineer has a stage, a model of it and a record logged in closed loop. This
# tutorial goes the whole way with clm-sim: load the record, identify a linear-in-the-parameters
# (LIP) feedforward, ask the diagnosis what the model gets wrong, extend the model with what it
# names and measure the gain in closed loop, fit a physics-guided neural network (PGNN), and
# export the feedforward as C that checks itself on the target.
#
# There is no measured record in the repository, so the first step makes one: clm-sim's
# emulated machine is the default stage with a **cogging force the model does not know** and a
# mass 8 % above the model's. Everything after that step sees only the record and the nominal
# model; the machine is used only to say whether the answers are right.
#
# Run [the script](record_to_feedforward.py) from the repository root with
# `python docs/tutorial/record_to_feedforward.py` (about half a minute), or open it as a
# notebook with
# `jupytext --to notebook docs/tutorial/record_to_feedforward.py`. The last step needs a C
# compiler (`cc`, `gcc` or `clang`). `tests/test_tutorial.py` runs it and checks what each step
# prints against the statements under **What must hold** below: those are the test's
# assertions. It is one record and one network draw: an illustration of the workflow, not a
# measurement of the methods (the [results pages](../results/paper_table.md) are that).

# %%
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from clm_sim import (ExperimentConfig, LIPFeedforward, PGNNFeedforward, PGNNSettings, Plant,
                     Testbed, Training, diagnose, load_model, load_record)
from clm_sim.effects.position import Cogging
from clm_sim.records.write import save_csv

work = Path(tempfile.mkdtemp(prefix="clm-tutorial-"))  # every file of the tutorial goes here

# %% [markdown]
# ## 1. A record from the machine
#
# The machine (`truth`) differs from the model (`plant`) in two ways: 8 % more mass and a
# cogging force of 3 N with a 16 mm pitch. The PID is designed on the model, as it would be on
# a real stage. The training run is the identification experiment: the r1 motion (17.6 s at
# 10 kHz) with a 50 N dither added to the controller output. It is written as a CSV, as a
# logger would write it.

# %%
model_plant = Plant(effects=())  # what the engineer believes: the rigid body, no parasitics
machine = Plant(mass=model_plant.mass * 1.08, effects=(
    Cogging(amplitude=3.0, period=0.016, phase=0.7),))
config = ExperimentConfig(plant=model_plant, truth=machine, training=Training(repeats=1))
testbed = Testbed(config)
run = testbed.training_run(seed=1)
save_csv(run, work / "record.csv")
print(f"machine: mass {machine.mass:.4f} kg, cogging 3 N over 16 mm")

# %% [markdown]
# ## 2. Load it
#
# `load_record` reads CSV, NPZ or MATLAB files holding at least `t, r, y, u` (s, m, m, N), and
# refuses, in one line naming the column, what is not a usable record (`columns=` and `scale=`
# rename and scale a logger's columns).

# %%
record = load_record(work / "record.csv")
print(f"record: {len(record)} samples at {1 / record.ts:.0f} Hz, "
      f"{record.y.min() * 1e3:.1f} to {record.y.max() * 1e3:.1f} mm")

# %% [markdown]
# ## 3. Identify a LIP
#
# `u = m a + fv v + fc sign(v) + fk y` by least squares on the filtered record.
#
# **What must hold:** the identified mass is within 1 % of the machine's (the model's is 8 %
# off). Its printed standard error assumes white residuals; the cogging force the LIP lacks is
# anything but white, so the error can exceed it many times.

# %%
lip = LIPFeedforward().fit(y=record.y, u=record.u, ts=record.ts)
lip.save(work / "lip.json")
for name, value in lip.theta_.items():
    print(f"LIP {name}: {value:.4f} ± {lip.std_[name]:.2g}")
print(f"LIP mass error: {100 * (lip.theta_['mass'] / machine.mass - 1):+.2f} %")

# %% [markdown]
# ## 4. What does the LIP get wrong?
#
# `diagnose` fits the force residual (measured force minus the model's inverse dynamics) with
# the effect library, names the effects that pass its significance and parsimony rules, extends
# the model with them and measures the gain on the final quarter of the record, which the
# search did not see. Its `summary()` is what `clm-sim diagnose` prints; `load_model` reads the
# LIP file as a model (`clm-sim diagnose record.csv --model lip.json` does the same).
#
# **What must hold:** the first finding is the cogging force, its pitch within 1 % of 16 mm and
# its amplitude within 10 % of 3 N, and the extended model at least halves the force residual
# on the held-out quarter.

# %%
diagnosis = diagnose(record, load_model(work / "lip.json"))
print(diagnosis.summary())
for finding in diagnosis.findings:
    print(f"finding: {finding.effect} " + json.dumps(
        {k: round(v, 6) for k, v in finding.values().items()}))

# %% [markdown]
# ## 5. Extend and simulate
#
# The extended LIP identifies the named effects' coefficients alongside `m, fv, fc, fk` (their
# nonlinear parameters, here the cogging pitch, stay as the diagnosis found them). Both
# feedforwards are replayed in closed loop on the machine on r2, a motion beyond the training
# range; the tracking error is the mean absolute error (MAE).
#
# **What must hold:** the extended LIP's MAE on r2 is less than a tenth of the LIP's, and the
# LIP's less than feedback alone.

# %%
extended = LIPFeedforward(effects=diagnosis.effects).fit(y=record.y, u=record.u, ts=record.ts)
mae = {"feedback only": testbed.replay(None, "r2").mae,
       "LIP": testbed.replay(lip, "r2").mae,
       "extended LIP": testbed.replay(extended, "r2").mae}
for name, value in mae.items():
    print(f"MAE r2 {name}: {value * 1e6:.3f} µm")

# %% [markdown]
# ## 6. A PGNN
#
# A physics-guided neural network: the same physical layer in parallel with a small tanh
# network, regularized toward the LIP's parameters (`lam`). A network of 8 neurons and 30
# Levenberg–Marquardt iterations keep this step short (the fit stops at that cap, not
# converged: `fit_.stop` says so); `rng` is the network's draw and must be given.
#
# **What must hold:** its MAE on r2 is below feedback alone's.

# %%
pgnn = PGNNFeedforward(hidden=8, lam=0.01, settings=PGNNSettings(max_iter=30)).fit(
    y=record.y, u=record.u, ts=record.ts, theta_lip=lip.theta_, rng=0)
pgnn.save(work / "pgnn")
print(f"PGNN: {pgnn.fit_.stop} after {pgnn.fit_.iterations} iterations, mass "
      f"{pgnn.theta_['mass']:.4f} kg")
print(f"MAE r2 PGNN: {testbed.replay(pgnn, 'r2').mae * 1e6:.3f} µm")

# %% [markdown]
# ## 7. Export to C and run its self-test
#
# `clm-sim export-ff` writes the feedforward as C99 (`clm_ff.h`, `clm_ff.c`) with a self-test
# (`clm_ff_selftest.c`: the product's force on a short motion, checked to 1e-9 of its peak).
# Compiled with a three-line `main`, the self-test is what a target runs once at start-up
# ([the export's contract](../export.md)). The C is limited by default to the data the model
# was fitted on (its positions, velocities, accelerations and forces, widened by 50 %), so the
# export reads that record: `--limits-from`. In a shell the first call is
# `clm-sim export-ff pgnn.pt --to c --out ff --limits-from record.csv`.
#
# **What must hold:** the self-test passes (exit code 0), and the limits are the record's.

# %%
subprocess.run([sys.executable, "-m", "experiments.cli", "export-ff", str(work / "pgnn.pt"),
                "--to", "c", "--out", str(work / "ff"), "--limits-from", str(work / "record.csv")],
               check=True)
(work / "ff" / "main.c").write_text(
    '#include <stdio.h>\n#include "clm_ff.h"\n'
    "int main(void) { static clm_ff_stream s; int failed = clm_ff_selftest(&s);\n"
    '  printf("%d\\n", failed); return failed != 0; }\n')
cc = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
ff = work / "ff"
subprocess.run([cc, "-std=c99", "-O2", "-I", str(ff), "-o", str(ff / "selftest"),
                str(ff / "main.c"), str(ff / "clm_ff.c"), str(ff / "clm_ff_selftest.c"), "-lm"],
               check=True)
done = subprocess.run([str(ff / "selftest")], capture_output=True, text=True)
print(f"C self-test: exit {done.returncode} ({'passed' if done.returncode == 0 else 'FAILED'})")
export = json.loads((ff / "export.json").read_text())
print(f"exported a {export['kind']} at ts = {export['ts']} s, window {export['lag']} samples "
      f"back and {export['lead']} ahead")
print(f"limits from {export['limits_from']}: position {export['r_min']:.4f} to "
      f"{export['r_max']:.4f} m, force {export['max_force']:.1f} N")

# %%
shutil.rmtree(work)
