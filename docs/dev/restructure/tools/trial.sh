#!/bin/sh
# The whole mechanical pipeline of PLAN32 §5.1 on a throwaway clone of /work/main (never on the repo itself).
set -e
P=/work/wt/plan32
rm -rf $P/trial && git clone -q /work/main $P/trial && cd $P/trial
PATH=$P/venv/bin:$PATH python3 $P/move.py --repo . --split > $P/trial_move.log 2>&1
cp move-report.txt $P/move-report.trial.txt
PY=/work/main/.venv/bin/python
$PY $P/hand/h1_registry.py . > /dev/null
$PY $P/hand/h2_h3.py . > /dev/null
$PY $P/lift.py --repo . > $P/trial_lift.log 2>&1
touch calibration/arm.py   # H: the Arm value, written by hand in the real step 5
echo "== names";   $PY $P/check_names.py . | head -5
echo "== imports"; (cd /tmp && PYTHONDONTWRITEBYTECODE=1 PYTHONPATH=$P/trial nice $PY $P/import_all.py | sed -n 2,8p)
echo "== SCCs";    IMPORTS_JSON=$P/trial_imports_final.json $PY $P/imports.py $P/trial && IMPORTS_JSON=$P/trial_imports_final.json $PY $P/analyse.py summary | grep "^##"
echo "== golden";  (cd /tmp && PYTHONDONTWRITEBYTECODE=1 OPENBLAS_NUM_THREADS=1 PYTHONPATH=$P/trial nice $PY $P/check_golden.py $P/golden_3bdd962)
echo "== import-linter"; PYTHONPATH=$P/trial nice $P/venv/bin/lint-imports $P/cfg/importlinter_target.ini --no-cache 2>&1 | grep -E "KEPT|BROKEN|^- " || true
