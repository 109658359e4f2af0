"""Import every product module alone: the project modules are dropped from sys.modules before each import (third
party stays loaded), so a module that only imports because another was imported first fails here. About 7-10 s of
CPU; the test suite runs the cheaper one-interpreter walk (tests/test_imports.py). Usage: PYTHONPATH=TREE python import_alone.py"""
import importlib, pkgutil, sys, time
ROOTS = ("calibration", "cell_config", "drivers", "app")
t0 = time.perf_counter()
names = []
for root in ROOTS:
    pkg = importlib.import_module(root)
    names += [root] + [m.name for m in pkgutil.walk_packages(pkg.__path__, root + ".") if not m.name.endswith("__main__")]
fails = []
for name in names:
    for m in [m for m in sys.modules if m.split(".")[0] in ROOTS]:
        del sys.modules[m]
    try:
        importlib.import_module(name)
    except Exception as e:
        fails.append(f"{name}: {type(e).__name__}: {e}")
print(len(names), "modules", len(fails), "fail", round(time.perf_counter() - t0, 1), "s")
print("\n".join(fails))
