"""The lab: tools around the renderer, not the renderer. Benchmarks (bench*, perf, bench_cycles), the numerical
stress suite, the seed's Monte Carlo study (montecarlo, mc_study) and scene builders for Cycles (bpy_scenes,
core_to_bpy).

`core/` and `addon/` never import this package and the Blender extension does not ship it; the `monte` command
and the tests import it. Modules here may import `core` and `addon` (the bpy ones need the bpy module).
"""
