"""Run by run_embed.cmake with PYTHONPATH = the install prefix's dist-packages only: the
installed package must import and find its libraries and plugins through its RPATH."""
import terramap

YAML = """version: 1
map: {resolution: 0.5, size: [8, 6], layers: [{name: elevation, unit: m, fill: 1.0}]}
source: {type: none}
pipeline:
  - {name: s, type: smooth_filter, params: {input_layer: elevation, output_layer: s, run_on: [tick]}}
"""
e = terramap.Engine.from_yaml(YAML)
e.push_tick(0.0)
print("installed python:", terramap.__file__, float(e.snapshot().layer("s").mean()))
