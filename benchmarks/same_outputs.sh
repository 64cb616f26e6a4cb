#!/bin/bash
# same_outputs.sh TREE OUT: what a refactor must leave unchanged, written from the checkout TREE
# into OUT: the paper table, the LIP baseline, the EMPS diagnosis and LIP identification, and the
# C and ONNX exports (LIP, PGNN, the diagnosis's extended model). Compare the OUTs of two
# checkouts with same_outputs_diff.sh. One BLAS thread (docs/reproducibility.md); needs
# ../shared/data/emps beside the repository and the .venv of README's set-up.
set -u
HERE=$(cd "$(dirname "$0")/.." && pwd); C=$HERE/.venv/bin/clm-sim; E=$HERE/../shared/data/emps
TREE=$(cd "$1" && pwd); mkdir -p "$2"; OUT=$(cd "$2" && pwd); cd "$TREE"
export PYTHONPATH=$TREE OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 SOURCE_DATE_EPOCH=1700000000
rm -rf "$OUT"/*
$C run experiments/configs/paper_table.yaml --out "$OUT/table" > "$OUT/table.stdout" 2>&1
$C run experiments/configs/lip_baseline.yaml --out "$OUT/lip" > "$OUT/lip.stdout" 2>&1
$C diagnose $E/DATA_EMPS.mat --validate $E/DATA_EMPS_PULSES.mat --model experiments/configs/emps_model.yaml \
  --columns y=qm,r=qg,u=vir --scale u=gtau --out "$OUT/diag" > "$OUT/diag.stdout" 2>&1
$C identify $E/DATA_EMPS.mat --columns y=qm,r=qg,u=vir --scale u=gtau --out "$OUT/ident" > "$OUT/ident.stdout" 2>&1
$C export-ff "$OUT/table/params/lip.json" --to c --out "$OUT/ff_lip" > "$OUT/ff_lip.stdout" 2>&1
P=$(ls "$OUT"/table/params/*seed0*.pt "$OUT"/table/params/*seed0* 2>/dev/null | head -1)
$C export-ff "$P" --to c --out "$OUT/ff_pgnn" > "$OUT/ff_pgnn.stdout" 2>&1
$C export-ff "$P" --to onnx --out "$OUT/ff_onnx" > "$OUT/ff_onnx.stdout" 2>&1
$C export-ff "$OUT/diag/diagnosis.json" --to c --out "$OUT/ff_ext" > "$OUT/ff_ext.stdout" 2>&1
echo done > "$OUT/DONE"
