#!/usr/bin/env python3
"""Checks the include rules between terramap's layers (docs/architecture.md, "Rules").

Every `#include <terramap/X/...>` in a layer's public headers and sources must name a layer that
layer may use; every `#include "..."` that leaves a layer's folder must do the same. Prints each
violation as file:line and exits 1 when there is one (CTest: Architecture.IncludeRules).

    python3 scripts/check_includes.py [REPO]
"""
import os
import re
import sys

# What each layer may include (itself always). The public headers (include/terramap/X) and the
# implementation (engine/X) of a layer share one rule.
ALLOWED = {
    "core": set(),
    "plugin": {"core"},
    "soil": {"core", "plugin"},  # plugin: header-only helpers a soil-estimating plugin uses
    "io": {"core"},
    "yaml": {"core"},
    "sim": {"core", "io", "soil", "yaml"},
    "pipeline": {"core", "plugin", "io", "yaml"},
    "eval": {"core", "plugin", "io", "soil", "sim", "pipeline", "yaml"},
}
# A plugin module is loaded by any host: it may not pull in the pipeline, the simulator or eval.
PLUGIN_ALLOWED = {"core", "plugin", "soil", "io"}
# Files of a plugin folder that are not part of its module (soil_pinn's training library, used
# by terramap-soil only) and may use eval as the tools do.
PLUGIN_EXCEPTIONS = {
    "plugins/soil_pinn/trainer.cpp": {"eval"},
    "plugins/soil_pinn/trainer.hpp": {"eval"},
    "plugins/soil_pinn/evaluation.cpp": {"eval"},
    "plugins/soil_pinn/evaluation.hpp": {"eval"},
}
SOURCE = re.compile(r"\.(h|hpp|c|cc|cpp|in)$")
ANGLE = re.compile(r'^\s*#\s*include\s*<terramap/([a-z_]+)/')
QUOTE = re.compile(r'^\s*#\s*include\s*"([^"]+)"')


def files_under(root, rel):
    base = os.path.join(root, rel)
    for dirpath, dirnames, filenames in os.walk(base):
        dirnames[:] = [d for d in dirnames if d != "tests"]
        for f in sorted(filenames):
            if SOURCE.search(f):
                yield os.path.relpath(os.path.join(dirpath, f), root)


def check_file(root, rel, layer, allowed, problems):
    folder = os.path.dirname(os.path.join(root, rel))
    with open(os.path.join(root, rel), encoding="utf-8", errors="replace") as fh:
        for no, line in enumerate(fh, 1):
            m = ANGLE.match(line)
            if m and m.group(1) != layer and m.group(1) not in allowed:
                problems.append(f"{rel}:{no}: {layer} may not include terramap/{m.group(1)}/ "
                                f"(allowed: {', '.join(sorted(allowed)) or 'nothing'})")
            q = QUOTE.match(line)
            if q:
                target = os.path.normpath(os.path.join(folder, q.group(1)))
                engine = os.path.join(root, "engine")
                if target.startswith(engine + os.sep):
                    other = os.path.relpath(target, engine).split(os.sep)[0]
                    if other != layer and other not in allowed:
                        problems.append(f"{rel}:{no}: {layer} may not include engine/{other}/ "
                                        f"({q.group(1)})")


def main():
    root = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else os.path.join(os.path.dirname(__file__), ".."))
    problems = []
    checked = 0
    for layer, allowed in ALLOWED.items():
        for rel in list(files_under(root, f"include/terramap/{layer}")) + list(files_under(root, f"engine/{layer}")):
            check_file(root, rel, layer, allowed, problems)
            checked += 1
    plugins = os.path.join(root, "plugins")
    for name in sorted(os.listdir(plugins)):
        if not os.path.isdir(os.path.join(plugins, name)):
            continue
        for rel in files_under(root, f"plugins/{name}"):
            check_file(root, rel, f"plugin {name}", PLUGIN_ALLOWED | PLUGIN_EXCEPTIONS.get(rel, set()), problems)
            checked += 1
    for p in problems:
        print(p)
    print(f"{checked} files checked, {len(problems)} include rule violations")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
