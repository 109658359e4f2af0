"""Import every module of the product in one interpreter; print the ones that fail (a runtime circle, a name
used before its definition after a split, a missing hand step). Usage: PYTHONPATH=TREE python import_all.py"""
import importlib, pkgutil, sys
fails, names = {}, []
def walk(pkg):
    m = importlib.import_module(pkg)
    names.append(pkg)
    for info in pkgutil.iter_modules(m.__path__, pkg + "."):
        if info.ispkg:
            try:
                walk(info.name)
            except Exception as e:
                fails[info.name] = f"{type(e).__name__}: {e}"
        else:
            names.append(info.name)
for pkg in ("calibration", "cell_config", "drivers", "app"):
    try:
        walk(pkg)
    except Exception as e:
        fails[pkg] = f"{type(e).__name__}: {e}"
for n in names:
    if n.endswith("__main__"):
        continue
    try:
        importlib.import_module(n)
    except (Exception, SystemExit) as e:
        fails[n] = f"{type(e).__name__}: {e}"
print(importlib.import_module("calibration").__file__)
print(len(names), "modules,", len(fails), "fail to import")
for k, v in fails.items():
    print(" ", k, "->", v[:200])
