#!/bin/bash
# (the before/after comparison of issue 32 step 0; outputs kept outside the repo; compare two with cmp.py A B)
# usage: run_baseline.sh COMMIT OUTDIR BENCH_FIT_PATH -- the step-0 outputs of issue 32 on a clean copy of COMMIT
set -u
C=$1; O=$2; BF=$3
W=${BASE_DIR:-/work/wt/move32_base}
rm -rf $W/src_$C && mkdir -p $W/src_$C $O && git -C /work/wt/move32 archive $C | tar -x -C $W/src_$C
R=$W/src_$C; cd $R
D=/work/shared/data/welding_motoman
export OPENBLAS_NUM_THREADS=1 PYTHONPATH=$R PYTHONDONTWRITEBYTECODE=1
PY=/work/wt/move32/.venv/bin/python
CC="$PY -m app.cli"
( time nice $CC diagnose --robot R1 --train $D/PH_grad_data/test0801_R1 --test $D/kinematic_raw_data/test0801_R1 --json $O/diagnose.json ) > $O/diagnose.out 2> $O/diagnose.err
( time nice $CC plan-dual --path sweep:200 --compile off --json $O/plan_dual.json --out $O/plan_dual_plan.json ) > $O/plan_dual.out 2> $O/plan_dual.err
( cd /tmp && time nice $PY /work/wt/move32/docs/dev/restructure/tools/check_golden.py /work/wt/move32/docs/dev/restructure/golden_3bdd962 ) > $O/golden.out 2> $O/golden.err
( time nice $CC demo --out $O/demo_out --json $O/demo.json --no-progress ) > $O/demo.out 2> $O/demo.err
( time nice $PY $BF --runs 1 --json $O/bench_fit.json ) > $O/bench_fit.out 2> $O/bench_fit.err
echo done > $O/DONE
